"""The exact reference: segment-against-prism tests, including the degenerate sight lines."""

from __future__ import annotations

import numpy as np
import shapely
import shapely.affinity

from topology.polygons import Polygons
from topology.pvs_reference import ReferenceConfig, Scene, eye_points, in_range, reference_visible, target_points


def scene(*buildings) -> Scene:
    return Scene(Polygons.from_shapely([shapely.box(*b[:4]) for b in buildings]), np.array([b[4] for b in buildings]))


def blocked(sc: Scene, eye, *targets) -> list[bool]:
    return sc.blocked_from(np.array(eye, float), np.array(targets, float)).tolist()


def test_plain_blocking_and_passing_over():
    sc = scene((10, -5, 20, 5, 10.0))
    assert blocked(sc, (0, 0, 2), (30, 0, 2)) == [True]
    assert blocked(sc, (0, 0, 30), (30, 0, 2)) == [False]  # high enough to pass over the roof
    assert blocked(sc, (0, 0, 2), (30, 20, 2)) == [False]  # beside it


def test_eye_on_a_wall():
    sc = scene((10, -5, 20, 5, 10.0))
    assert blocked(sc, (10, 0, 2), (0, 0, 2), (0, 30, 2)) == [False, False]  # looking away from the wall
    assert blocked(sc, (10, 0, 2), (30, 0, 2)) == [True]  # looking through the building


def test_eye_on_the_roof_edge():
    sc = scene((10, -5, 20, 5, 10.0))
    assert blocked(sc, (10, 0, 10), (0, 0, 1)) == [False]  # down, away from the roof
    assert blocked(sc, (10, 0, 10), (30, 0, 1)) == [True]  # down, across the roof
    assert blocked(sc, (10, 0, 10), (30, 0, 10)) == [False]  # level with the roof: grazing


def test_grazing_a_corner_and_running_along_a_wall():
    sc = scene((10, 0, 20, 10, 10.0))
    assert blocked(sc, (0, 20, 2), (20, 0, 2)) == [True]  # enters through the corner (10, 10)
    assert blocked(sc, (0, 20, 2), (30, -10, 2)) == [True]  # through the interior
    assert blocked(sc, (0, 10, 2), (30, 10, 2)) == [False]  # along the wall y = 10
    assert blocked(sc, (0, 0, 2), (30, 0, 2)) == [False]  # along the wall y = 0
    assert blocked(sc, (0, 20, 2), (20, 0, 2), (5, 25, 2)) == [True, False]
    assert blocked(sc, (0, 10, 2), (20, 10, 2)) == [False]  # to a corner along a wall
    assert blocked(sc, (10, 10, 2), (20, 0, 2)) == [True]  # the diagonal through two corners
    assert blocked(sc, (0, 20, 2), (10, 10, 2)) == [False]  # ends at the corner


def test_touching_a_corner_only():
    sc = scene((10, 0, 20, 10, 10.0))
    assert blocked(sc, (10, 20, 2), (30, 0, 2)) == [False]  # touches the corner (20, 10), stays outside
    assert blocked(sc, (0, 20, 2), (20, 20, 2)) == [False]
    assert blocked(sc, (5, 15, 2), (15, 5, 2)) == [True]  # through the corner (10, 10) into the interior


def test_target_inside_a_building_is_blocked():
    sc = scene((10, 0, 20, 10, 10.0))
    assert blocked(sc, (0, 50, 2), (15, 5, 2)) == [True]


def test_no_buildings():
    sc = Scene(Polygons.empty(), np.zeros(0))
    assert blocked(sc, (0, 0, 1), (10, 10, 1), (20, 0, 3)) == [False, False]


def test_reference_visible_end_to_end():
    # a wall between the view cell and one of two cells
    b = Polygons.from_shapely([shapely.box(0, 20, 100, 40)])
    sc = Scene(b, np.array([30.0]))
    cells = Polygons.from_shapely([shapely.box(0, 0, 100, 20), shapely.box(0, 40, 100, 60)])
    rc = ReferenceConfig(eyes_xy=3, eyes_z=2, target_spacing=4.0)
    tp, tc = target_points(cells, np.array([4.0, 4.0]), rc.target_spacing, rc.target_levels)
    low = np.array([40, 0, 0, 60, 20, 20.0])
    high = np.array([40, 0, 80, 60, 20, 100.0])
    cand = in_range(low, cells.to_shapely(), 500.0)
    assert reference_visible(sc, low, tp, tc, cand, rc).tolist() == [0]
    assert reference_visible(sc, high, tp, tc, cand, rc).tolist() == [0, 1]
    assert len(eye_points(low, rc)) == 18


def _geos_blocked(polys, heights, a, b) -> bool:
    """An independent check with GEOS: the parts of the segment over a footprint, z at their ends."""
    line = shapely.LineString([a[:2], b[:2]])
    d = np.asarray(b[:2]) - np.asarray(a[:2])
    dd = float(d @ d)
    for poly, h in zip(polys, heights, strict=True):
        for part in shapely.get_parts(line.intersection(poly)):
            if part.geom_type != "LineString" or part.length <= 1e-9:
                continue
            if not poly.contains(part.interpolate(0.5, normalized=True)):
                continue
            ts = [float((np.asarray(c) - a[:2]) @ d) / dd for c in (part.coords[0], part.coords[-1])]
            if min(a[2] + t * (b[2] - a[2]) for t in ts) < h - 1e-9:
                return True
    return False


def test_agrees_with_geos_on_random_segments():
    rng = np.random.default_rng(4)
    polys = []
    for _ in range(12):
        cx, cy = rng.uniform(0, 200, 2)
        w, h = rng.uniform(5, 30, 2)
        polys.append(shapely.affinity.rotate(shapely.box(cx - w, cy - h, cx + w, cy + h), rng.uniform(0, 90)))
    merged = shapely.get_parts(shapely.union_all(polys[:6]))  # some non-convex footprints
    polys = list(merged) + polys[6:]
    heights = rng.uniform(5, 40, len(polys))
    sc = Scene(Polygons.from_shapely(polys), heights)
    n_blocked = n_tested = 0
    for _ in range(6):
        eye = np.array([*rng.uniform(-20, 220, 2), rng.uniform(0, 60)])
        if sc.inside(eye[:1], eye[1:2], eye[2:]).any():
            continue
        targets = np.column_stack([rng.uniform(-20, 220, (150, 2)), rng.uniform(0, 5, 150)])
        got = sc.blocked_from(eye, targets)
        want = [_geos_blocked(polys, heights, eye, t) for t in targets]
        assert got.tolist() == want
        n_blocked += sum(want)
        n_tested += len(want)
    assert 0.1 * n_tested < n_blocked < 0.9 * n_tested
