"""The lateral cover over C tables (`_waytable.pyx`, issue 22): `py_hypot` is Python's `math.hypot` bit for bit,
and `WayTable.way_cells` gives the pure candidate loop's cells (`_way_cells_py` over the widened bucket's box
test) on degenerate geometry, at random points, vertices and cell boundaries, and on hostile arguments (NaN,
infinities, -0.0, subnormals, huge values), with and without `skip` / `only`."""

import math
import random
import struct

import pytest

from entitynet.client import lateral, netview
from entitynet.client.lateral import WIDE, WIDE_SIZE, near_index
from entitynet.client.placement import Placer
from tests.entitynet.client.test_lateral import _degenerate, _points
from tests.entitynet.client_fixtures import ALL, area_square, cross, parallel
from topology.raw import PEDESTRIAN, VEHICLE

waytable = pytest.importorskip("entitynet.client._waytable", reason="the C tables are not built here")

HARD = [0.0, -0.0, 5e-324, -5e-324, 1e-310, 2.2250738585072014e-308, 1e-300, 1.0, 3.0, 4.0, 1e16, 1e154, 1e200,
        1e308, 1.7976931348623157e308, -1e308, math.inf, -math.inf, math.nan]


def _bits(v: float):
    return "nan" if v != v else struct.pack("=d", v)


def test_py_hypot_is_pythons_hypot_bit_for_bit():
    """Every pair of hard values, and random pairs over the whole exponent range and at street scale (where
    the sum of squares' rounding decides the last bit)."""
    for a in HARD:
        for b in HARD:
            assert _bits(waytable.py_hypot(a, b)) == _bits(math.hypot(a, b)), (a, b)
    rng = random.Random(3)
    for _ in range(100_000):
        e1 = rng.randint(-1074, 1023)
        e2 = min(max(e1 + rng.randint(-60, 60), -1074), 1023)
        a = math.ldexp(rng.random(), e1) * rng.choice((1, -1))
        b = math.ldexp(rng.random(), e2) * rng.choice((1, -1))
        assert _bits(waytable.py_hypot(a, b)) == _bits(math.hypot(a, b)), (a, b)
        a, b = rng.uniform(-50.0, 50.0), rng.uniform(-50.0, 50.0)
        assert _bits(waytable.py_hypot(a, b)) == _bits(math.hypot(a, b)), (a, b)


def _pure(idx, x, y, *rest):
    """`NearIndex.way_cells` by the pure reference: the widened bucket's box test, then `_way_cells_py`."""
    r = rest[2]
    x0, y0, x1, y1 = x - r, y - r, x + r, y + r
    rows = idx.wide.get((math.floor(x / WIDE_SIZE), math.floor(y / WIDE_SIZE)), ())
    cand = [w for _e, bx0, by0, bx1, by1, w in rows if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0)]
    return lateral._way_cells_py(cand, x, y, *rest)


def _table(idx):
    return waytable.WayTable(idx.wide, idx._ways, idx.placer.net)


@pytest.mark.parametrize("topo", [_degenerate(), cross(arm=100.0, street_cell_max=15.0), parallel(gap=6.0),
                                  area_square()])
def test_the_table_gives_the_pure_loops_cells(topo):
    net = netview(topo)
    rng = random.Random(9)
    for networks in (PEDESTRIAN, VEHICLE, ALL):
        idx = near_index(Placer(net, networks))
        table = _table(idx)
        for x, y in _points(net, rng):
            key = (math.floor(x / WIDE_SIZE), math.floor(y / WIDE_SIZE))
            for r in (0.0, 6.0, 12.5, WIDE):
                ang = rng.uniform(0.0, 2.0 * math.pi)
                dx, dy = rng.choice([(math.cos(ang), math.sin(ang)), (0.0, 0.0)])
                back, ahead = rng.choice([(5.0, 30.0), (0.0, 0.0), (10.83, 15.0)])
                skip = set(rng.sample(range(net.n_edges), rng.randint(0, 2)))
                only = rng.choice([None, frozenset({0, 2})])
                args = (x, y, dx, dy, r, back, ahead, skip, only)
                assert table.way_cells(key, *args) == _pure(idx, *args), args


def test_the_table_on_hard_arguments():
    """NaN, infinities, -0.0, subnormals and huge values as direction, radius and reach (the position stays
    finite: the bucket's key, `math.floor`, raises on NaN before either loop runs)."""
    rng = random.Random(13)
    net = netview(_degenerate())
    idx = near_index(Placer(net, ALL))
    table = _table(idx)
    pts = _points(net, rng)

    def pick(normal):
        return rng.choice(HARD) if rng.random() < 0.4 else normal

    for _ in range(3000):
        x, y = rng.choice(pts)
        key = (math.floor(x / WIDE_SIZE), math.floor(y / WIDE_SIZE))
        args = (x, y, pick(1.0), pick(-0.5), pick(12.5), pick(5.0), pick(30.0), set(), rng.choice([None, {0, 2}]))
        assert [_bits(float(c)) for c in table.way_cells(key, *args)] == [
            _bits(float(c)) for c in _pure(idx, *args)], args
        assert all(type(c) is int for c in table.way_cells(key, *args))


def test_an_unknown_bucket_has_no_cells():
    net = netview(_degenerate())
    table = _table(near_index(Placer(net, ALL)))
    assert table.way_cells((10**9, -(10**9)), 0.0, 0.0, 1.0, 0.0, 10.0, 5.0, 30.0, set(), None) == []


def test_near_index_uses_the_table_where_built():
    """`NearIndex.way_cells` answers through the table (r <= WIDE) and gives the pure answer."""
    net = netview(cross(arm=100.0, street_cell_max=15.0))
    idx = near_index(Placer(net, ALL))
    rng = random.Random(2)
    for x, y in _points(net, rng)[:200]:
        args = (x, y, 1.0, 0.0, 10.0, 5.0, 30.0, set(), None)
        assert idx.way_cells(*args) == _pure(idx, *args)
    if lateral._WayTable is not None:
        assert idx._table is not None


def test_more_cells_than_the_c_buffer():
    """Over 64 cells in one answer (1 m street cells, a long reach): the ones past the C buffer are checked in a
    list, still in order and without repeats."""
    net = netview(cross(arm=150.0, street_cell_max=1.0))
    idx = near_index(Placer(net, ALL))
    table = _table(idx)
    rng = random.Random(4)
    longest = 0
    for x, y in _points(net, rng)[:300]:
        key = (math.floor(x / WIDE_SIZE), math.floor(y / WIDE_SIZE))
        args = (x, y, 1.0, 0.0, WIDE, 200.0, 200.0, set(), None)
        got = table.way_cells(key, *args)
        assert got == _pure(idx, *args)
        longest = max(longest, len(got))
    assert longest > 64


def test_the_table_keys_by_the_indexs_bucket_size():
    assert waytable.wide_size() == WIDE_SIZE


def _paths(net, rng):
    from entitynet.client.path import Path, follow

    paths = [Path(net, [(e, d)]) for e in range(net.n_edges) for d in (1, -1)]
    for p in list(paths):
        more = follow(net, p.edges[-1], ALL, rng.uniform(0.0, 150.0), max_edges=3)
        if more:
            paths.append(p.extended(more))
    return paths


def _pure_path(idx, path, s, r, back, ahead, only):
    """`NearIndex.path_cells`'s pure lines: the points, `_edges_between` and the edge at s, then `_pure`."""
    x, y = path.xy(s)
    hx, hy = path.xy(min(s + 1.0, path.length))
    bx, by = path.xy(max(s - 1.0, 0.0))
    skip = lateral._edges_between(path, s - back, s + ahead)
    skip.add(path.locate(s)[0])
    return _pure(idx, x, y, hx - bx, hy - by, r, back, ahead, skip, only)


def _answer(fn, *args):
    try:
        return fn(*args)
    except (ValueError, OverflowError) as exc:
        return type(exc).__name__


@pytest.mark.parametrize("topo", [_degenerate(), cross(arm=100.0, street_cell_max=15.0), parallel(gap=6.0),
                                  area_square()])
def test_path_cells_gives_the_pure_answer(topo):
    """`WayTable.path_cells` against the pure lines on every edge both ways and paths of several edges, at
    random coordinates, the path's vertices and ends and beyond, and at NaN, infinities and -0.0 (whose
    bucket key raises as `math.floor` does), with reaches of none, usual and NaN."""
    net = netview(topo)
    rng = random.Random(17)
    idx = near_index(Placer(net, ALL))
    table = _table(idx)
    for p in _paths(net, rng):
        coords = [rng.uniform(-5.0, p.length + 5.0) for _ in range(12)] + list(p.cum)
        coords += [-0.0, math.nextafter(p.length, math.inf), math.inf, -math.inf, math.nan]
        for s in coords:
            r = rng.choice([0.0, 10.0, WIDE])
            back, ahead = rng.choice([(5.0, 30.0), (0.0, 0.0), (10.83, 15.0), (math.nan, 5.0), (5.0, math.inf)])
            only = rng.choice([None, frozenset({0, 2})])
            args = (p, s, r, back, ahead, only)
            assert _answer(table.path_cells, *args) == _answer(_pure_path, idx, *args), (p, s, back, ahead)


def test_path_cells_skips_a_long_run_of_the_paths_edges():
    """More of the path's own edges in reach than the C buffer holds (65 short edges): they go to a set."""
    from tests.entitynet.client_fixtures import make_topology

    nodes = {f"N{i}": (2.0 * i, 0.0) for i in range(70)} | {"P": (0.0, 4.0), "Q": (140.0, 4.0)}
    edges = [(f"N{i}", f"N{i + 1}") for i in range(69)] + [("P", "Q")]
    net = netview(make_topology(nodes, edges, junction_radius=0.5, street_cell_max=15.0))
    from entitynet.client.path import Path

    path = Path(net, [(e, 1) for e in range(69)])
    idx = near_index(Placer(net, ALL))
    table = _table(idx)
    for s in (0.0, 20.0, 70.0, 137.0):
        args = (path, s, WIDE, 200.0, 200.0, None)
        assert table.path_cells(*args) == _pure_path(idx, *args)
        assert table.path_cells(*args)  # the parallel way's cells, the path's own skipped


def test_areas_near_gives_the_placers_answer():
    """`NearIndex.areas_near` (compiled once the placer's grid is built) is `Placer.areas_near`, at random
    points, the rings' vertices and box corners, for radii of none to wide, and the same error for NaN and the
    infinities."""
    net = netview(area_square())
    rng = random.Random(21)
    placer = Placer(net, ALL)
    idx = near_index(placer)
    placer.areas_near(0.0, 0.0, 1.0)  # builds the grid
    pts = [(rng.uniform(-150.0, 250.0), rng.uniform(-150.0, 250.0)) for _ in range(400)]
    for (_i, bx0, by0, bx1, by1) in [row for rows in placer._area_rows.values() for row in rows]:
        pts += [(bx0, by0), (bx1, by1), (bx0 - 10.0, by0), (bx1 + 10.0, by1), (math.nextafter(bx0 - 10.0, 0.0), by0)]
    for x, y in pts:
        for r in (0.0, 10.0, 25.0, 80.0):
            assert idx.areas_near(x, y, r) == placer.areas_near(x, y, r), (x, y, r)
    for x, y, r in [(math.nan, 0.0, 10.0), (0.0, math.inf, 10.0), (0.0, 0.0, math.nan), (-0.0, -0.0, 0.0)]:
        assert _answer(idx.areas_near, x, y, r) == _answer(placer.areas_near, x, y, r)
    if lateral._areas_near is not None:
        x, y = pts[0]
        assert waytable.areas_near(placer._area_rows, 100.0, x, y, 10.0) == placer.areas_near(x, y, 10.0)
