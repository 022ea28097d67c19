"""`PlacementIndex.place_many` answers as `place` does, point for point (kind, index, distance exactly)."""

from __future__ import annotations

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
