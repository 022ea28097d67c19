"""The exact reference: segment-against-prism tests, including the degenerate sight lines."""

from __future__ import annotations

import numpy as np
import shapely

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
