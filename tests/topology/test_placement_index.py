"""`PlacementIndex.place_many` and `prime` answer as `place` does, point for point (exactly)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from topology.raw import PEDESTRIAN, TRAM, VEHICLE

_KIND = {None: 0, "edge": 1, "area": 2}


def _points(topo, rng) -> np.ndarray:
    """Random points over the map and beyond it, the map's vertices (equidistant from every edge meeting there:
    the lowest id must win) and points inside areas."""
    xy = topo.edge_geom_xy
    lo, hi = xy.min(axis=0) - 50.0, xy.max(axis=0) + 50.0
    rand = rng.uniform(lo, hi, size=(300, 2))
    verts = xy[rng.choice(len(xy), 150, replace=False)]
    areas = [p.representative_point() for p in topo.area_polygons.to_shapely()[:40]]
    return np.vstack([rand, verts, np.array([[a.x, a.y] for a in areas]).reshape(-1, 2)])


@pytest.mark.parametrize("networks", [PEDESTRIAN, VEHICLE, TRAM, PEDESTRIAN | VEHICLE | TRAM])
def test_place_many_equals_place(helsinki, networks):
    idx = helsinki.placement_index()
    pts = _points(helsinki, np.random.default_rng(networks))
    kind, index, dist = idx.place_many(pts, networks)
    seen = set()
    for (x, y), k, i, d in zip(pts.tolist(), kind.tolist(), index.tolist(), dist.tolist(), strict=True):
        p = idx.place(x, y, networks)
        assert k == _KIND[None if p is None else p.kind]
        assert i == p.index and d == p.distance  # (exact: the same GEOS distances)
        seen.add(p.kind)
    assert seen >= {"edge"} and (networks == TRAM or "area" in seen)


def test_place_many_empty_and_bad_input(helsinki):
    idx = helsinki.placement_index()
    kind, index, dist = idx.place_many(np.zeros((0, 2)), VEHICLE)
    assert len(kind) == len(index) == len(dist) == 0
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="non-finite"):
            idx.place_many(np.array([[0.0, 0.0], [bad, 1.0]]), VEHICLE)


@pytest.mark.parametrize("networks", [PEDESTRIAN, VEHICLE, TRAM, PEDESTRIAN | VEHICLE | TRAM])
def test_prime_answers_what_place_answers_bit_for_bit(helsinki, networks):
    """`prime` then `place`: the memo's answers are `place`'s own, every field to the bit (repr tells -0.0 and
    the last bit apart), and each primed point is a lookup (`primed_hits`)."""
    idx = helsinki.placement_index()
    pts = _points(helsinki, np.random.default_rng(10 + networks))
    idx.prime(np.zeros((0, 2)), networks)  # (an empty batch clears the memo)
    ref = [idx.place(x, y, networks) for x, y in pts.tolist()]
    assert idx.prime(pts, networks) == len(pts)
    hits = idx.primed_hits
    got = [idx.place(x, y, networks) for x, y in pts.tolist()]
    assert idx.primed_hits - hits == len(pts)
    assert [repr(p) for p in got] == [repr(p) for p in ref]
    assert {p.kind for p in ref if p} >= {"edge"}
    # another mask is not answered from this one's batch
    other = VEHICLE if networks == PEDESTRIAN else PEDESTRIAN
    hits = idx.primed_hits
    assert repr(idx.place(*pts[0].tolist(), other)) == repr(_fresh(helsinki, pts[0], other))
    assert idx.primed_hits == hits


def _fresh(topo, pt, networks):
    """`place` on an index that holds no batch."""
    from topology.placement_index import PlacementIndex

    return PlacementIndex(topo).place(float(pt[0]), float(pt[1]), networks)


def test_prime_batches_replace_or_keep_and_skip_bad_points(helsinki):
    idx = helsinki.placement_index()
    a = np.array([[10.5, 20.25], [-30.0, 44.0]])
    b = np.array([[100.5, 80.0]])
    idx.prime(a, PEDESTRIAN)
    idx.prime(b, VEHICLE, keep=True)  # beside the first batch
    hits = idx.primed_hits
    idx.place(10.5, 20.25, PEDESTRIAN)
    idx.place(100.5, 80.0, VEHICLE)
    assert idx.primed_hits == hits + 2
    idx.prime(b, VEHICLE)  # in place of both
    idx.place(10.5, 20.25, PEDESTRIAN)
    assert idx.primed_hits == hits + 2
    # non-finite points and points on an axis are not kept; `place` still refuses a non-finite point
    bad = np.array([[np.nan, 1.0], [np.inf, 2.0], [0.0, 5.0], [-0.0, 5.0], [3.0, 4.0]])
    assert idx.prime(bad, PEDESTRIAN) == 1
    with pytest.raises(ValueError, match="non-finite"):
        idx.place(math.nan, 1.0, PEDESTRIAN)
    assert repr(idx.place(-0.0, 5.0, PEDESTRIAN)) == repr(_fresh(helsinki, (-0.0, 5.0), PEDESTRIAN))
