"""The fast PVS: the hard cases of issue 3, and agreement with the exact reference on a synthetic city."""

from __future__ import annotations

import types

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from topology.polygons import Polygons
from topology.pvs import PvsConfig, compute_pvs
from topology.pvs_index import PvsIndex
from topology.pvs_reference import ReferenceConfig, Scene, in_range, reference_visible, synthetic_city, target_points

FAST = dict(workers=1, raster=2.0, ray_spacing=1.5)


def boxes(*bs) -> Polygons:
    return Polygons.from_shapely([shapely.box(*b) for b in bs])


def pvs(bld, bh, cells, bounds, **kw):
    cfg = PvsConfig(**{**FAST, **kw})
    ch = np.full(len(cells), 4.0)
    return compute_pvs(bld, np.asarray(bh, float), cells, ch, bounds, cfg)


def reference(bld, bh, cells, result, v, cfg=None):
    scene = Scene(bld, np.asarray(bh, float))
    rc = cfg or ReferenceConfig(eyes_xy=4, eyes_z=2, target_spacing=2.0)
    tp, tc = target_points(cells, np.full(len(cells), 4.0), rc.target_spacing, rc.target_levels)
    box = result.grid.boxes()[v]
    cand = in_range(box, cells.to_shapely(), result.config.view_distance)
    return reference_visible(scene, box, tp, tc, cand, rc)


def view_cell_at(result, x, y, z) -> int:
    return PvsIndex.from_result(result).view_cell_of(x, y, z)


def test_map_without_buildings_sees_everything_in_range():
    cells = boxes((0, 0, 20, 10), (100, 0, 120, 10), (190, 190, 200, 200), (60, 100, 70, 160))
    r = pvs(Polygons.empty(), [], cells, (0, 0, 200, 200), view_distance=120.0)
    polys = cells.to_shapely()
    for v, box in enumerate(r.grid.boxes()):
        want = np.flatnonzero(shapely.distance(shapely.box(box[0], box[1], box[3], box[4]), polys) <= 120.0)
        assert r.pvs_of(v).tolist() == want.tolist()
    assert r.grid.n_view_cells == 10 * 10 * 5


def test_tiny_map_with_one_street():
    cells = boxes((0, 20, 60, 36))
    r = pvs(Polygons.empty(), [], cells, (0, 0, 60, 60), cell_size=20.0)
    assert r.grid.index.shape == (5, 3, 3)
    assert all(r.pvs_of(v).tolist() == [0] for v in range(r.grid.n_view_cells))
    idx = PvsIndex.from_result(r)
    assert idx.cells_at(30, 28, 2).tolist() == [0]


def test_wall_between_two_streets_hides_the_far_one_at_street_level_only():
    # two parallel streets separated by a 40 m long, 20 m thick, 30 m tall block
    bld = boxes((0, 20, 100, 40))
    cells = boxes((0, 0, 100, 20), (0, 40, 100, 60))
    r = pvs(bld, [30.0], cells, (0, 0, 100, 60), view_distance=200.0)
    low = view_cell_at(r, 50, 5, 1)
    assert r.pvs_of(low).tolist() == [0]
    high = view_cell_at(r, 50, 5, 90)
    assert r.pvs_of(high).tolist() == [0, 1]


def test_viewpoint_exactly_on_wall_and_roof_edge():
    # the view-cell grid lines coincide with the building's walls and its roof with a layer top
    bld = boxes((20, 20, 40, 40))
    cells = boxes((0, 0, 60, 16), (0, 44, 60, 60), (44, 0, 60, 60), (0, 0, 16, 60))
    r = pvs(bld, [20.0], cells, (0, 0, 60, 60), view_distance=200.0)
    for x, y, z in [(30, 30, 30), (10, 30, 10), (30, 50, 10), (50, 50, 10), (10, 10, 10)]:
        v = view_cell_at(r, x, y, z)
        assert v >= 0
        ref = reference(bld, [20.0], cells, r, v)
        assert set(ref.tolist()) <= set(r.pvs_of(v).tolist()), (x, y, z)
    # the view cell on the roof (20-40 m over the building) sees every street around it
    assert r.pvs_of(view_cell_at(r, 30, 30, 30)).tolist() == [0, 1, 2, 3]


def test_grazing_corner_and_along_wall_are_visible():
    # the view cell x 0-20, y 20-40 touches the building's corner (20, 40); cell 1 lies beyond the building
    # on the line of its wall y = 40, so it is seen only by sight lines grazing the corner / along the wall
    bld = boxes((20, 0, 60, 40))
    cells = boxes((0, 40, 20, 60), (60, 40, 80, 60), (60, 0, 80, 20))
    r = pvs(bld, [25.0], cells, (0, 0, 80, 60), view_distance=200.0)
    v = view_cell_at(r, 10, 30, 5)
    ref = reference(bld, [25.0], cells, r, v)
    assert ref.tolist() == [0, 1]  # cell 2 is behind the building
    assert set(ref.tolist()) <= set(r.pvs_of(v).tolist())


def test_buildings_taller_than_the_stack():
    bld = boxes((40, 0, 60, 60))
    cells = boxes((0, 0, 20, 60), (80, 0, 100, 60))
    r = pvs(bld, [150.0], cells, (0, 0, 100, 60), view_distance=300.0)
    assert (r.grid.index[:, :, 2] == -1).all()  # the whole column stack is inside the tower
    for z in (5, 50, 95):
        assert r.pvs_of(view_cell_at(r, 10, 30, z)).tolist() == [0]
    idx = PvsIndex.from_result(r)
    assert idx.view_cell_of(50, 30, 50) == -1
    answer = idx.lookup_cell(50, 30, 50)
    assert answer >= 0 and r.grid.coords()[0][answer] == r.grid.nz - 1


def test_view_cells_partly_inside_buildings():
    # a 30 m building covers column (1, 1) wholly and column (1, 2) mostly, leaving a 2 m strip
    bld = boxes((20, 20, 40, 40), (40, 20, 58, 40))
    cells = boxes((0, 0, 80, 16), (0, 44, 80, 60))
    r = pvs(bld, [30.0, 30.0], cells, (0, 0, 80, 60), view_distance=200.0)
    assert r.grid.index[0, 1, 1] == -1 and r.grid.index[1, 1, 1] >= 0
    v = int(r.grid.index[0, 1, 2])
    assert v >= 0  # partly inside: kept
    ref = reference(bld, [30.0, 30.0], cells, r, v)
    assert len(ref) and set(ref.tolist()) <= set(r.pvs_of(v).tolist())


def test_cell_at_the_edge_of_the_map_and_clamping():
    cells = boxes((0, 0, 10, 10), (190, 190, 200, 200))
    r = pvs(boxes((80, 80, 120, 120)), [50.0], cells, (0, 0, 200, 200), view_distance=100.0)
    idx = PvsIndex.from_result(r)
    corner = idx.view_cell_of(1, 1, 1)
    assert r.pvs_of(corner).tolist() == [0]
    assert idx.view_cell_of(-500, -500, -20) == corner  # clamped into the grid
    assert idx.cells_at(-500, -500, -20).tolist() == [0]
    assert idx.view_cell_of(1, 1, 1e6) == idx.view_cell_of(1, 1, 99)
    for bad in [(float("nan"), 0, 0), (0, float("inf"), 0), (0, 0, -float("inf"))]:
        with pytest.raises(ValueError):
            idx.cells_at(*bad)


def test_agrees_with_the_exact_reference_on_a_synthetic_city():
    bf, bh, cf, ch, bounds = synthetic_city(3, 3, seed=5)
    r = compute_pvs(bf, bh, cf, ch, bounds, PvsConfig(**FAST, view_distance=200.0))
    scene = Scene(bf, bh)
    rc = ReferenceConfig()
    tp, tc = target_points(cf, ch, rc.target_spacing, rc.target_levels)
    rng = np.random.default_rng(0)
    iz, _, _ = r.grid.coords()
    fn = vis = 0
    for k in range(r.grid.nz):
        v = int(rng.choice(np.flatnonzero(iz == k)))
        box = r.grid.boxes()[v]
        ref = reference_visible(scene, box, tp, tc, in_range(box, cf.to_shapely(), 200.0), rc)
        fn += len(np.setdiff1d(ref, r.pvs_of(v)))
        vis += len(ref)
    assert vis > 0 and fn / vis <= 0.01
    # and the PVS culls: street level sees far fewer cells than the distance cut
    street = iz == 0
    assert np.diff(r.offsets)[street].mean() < 0.8 * r.range_count[street].mean()


def test_index_round_trip_through_topology_extra_and_meta():
    bf, bh, cf, ch, bounds = synthetic_city(2, 2, seed=2)
    r = compute_pvs(bf, bh, cf, ch, bounds, PvsConfig(**FAST, view_distance=150.0))
    topo = types.SimpleNamespace(meta={"pvs": r.meta()}, extra=r.to_extra())
    assert all(k.startswith("pvs_") for k in topo.extra)
    idx = PvsIndex.from_topology(topo)
    iz, iy, ix = r.grid.coords()
    for v in range(0, r.grid.n_view_cells, 7):
        x = r.grid.x0 + (ix[v] + 0.5) * r.grid.size
        y = r.grid.y0 + (iy[v] + 0.5) * r.grid.size
        z = (iz[v] + 0.5) * r.grid.size
        assert idx.cells_at(x, y, z).tolist() == r.pvs_of(v).tolist()
    import json

    json.dumps(r.meta())


def test_bad_inputs_are_rejected():
    with pytest.raises(ValueError):
        pvs(boxes((0, 0, 1, 1)), [np.nan], boxes((2, 2, 3, 3)), (0, 0, 10, 10))
    with pytest.raises(ValueError):
        pvs(Polygons.empty(), [], boxes((2, 2, 3, 3)), (0, 0, -10, 10))
    with pytest.raises(ValueError):
        PvsConfig(view_distance=-1).validate()
    with pytest.raises(ValueError):
        PvsConfig.from_quality("ultra")


@pytest.fixture(scope="module")
def tower_city():
    # a synthetic city plus a 150 m tower covering whole columns (a hole through the whole stack)
    bf, bh, cf, ch, bounds = synthetic_city(2, 2, seed=9)
    polys = list(bf.to_shapely()) + [shapely.box(100, 20, 140, 60)]
    heights = np.concatenate([bh, [150.0]])
    r = compute_pvs(Polygons.from_shapely(polys), heights, cf, ch, bounds, PvsConfig(**FAST, view_distance=120.0))
    assert (r.grid.index < 0).all(axis=0).any()
    return r, PvsIndex.from_result(r)


@settings(max_examples=200, deadline=None)
@given(st.floats(-100, 300), st.floats(-100, 300), st.floats(-50, 200))
def test_lookup_anywhere_answers_a_kept_view_cell(tower_city, x, y, z):
    r, idx = tower_city
    own = idx.view_cell_of(x, y, z)
    used = idx.lookup_cell(x, y, z)
    assert -1 <= own < r.grid.n_view_cells and 0 <= used < r.grid.n_view_cells
    if own >= 0:
        assert used == own
    cells = idx.cells_at(x, y, z)
    assert cells.tolist() == r.pvs_of(used).tolist()
    assert np.all(np.diff(cells) > 0) and (len(cells) == 0 or (cells[0] >= 0 and cells[-1] < r.n_cells))
