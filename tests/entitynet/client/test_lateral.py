"""The lateral cover's per-edge tables (issue 22): `NearIndex.way_cells` and `_edges_between` give exactly what
the publish computed before them (`Placer.edges_near`, `Placer.project_on`, `NetView.point` per candidate, and
the path's edges by a full scan), also on degenerate geometry: a zero-length edge, a zero-length segment inside
an edge, edges of several segments, a position exactly on a node or a cell boundary, no direction at all."""

import math
import random
import struct
import subprocess
import sys
from pathlib import Path as FilePath

import pytest

from entitynet.client import lateral, netview
from entitynet.client.lateral import _edges_between, near_index
from entitynet.client.path import Path
from entitynet.client.placement import Placer
from tests.entitynet.client_fixtures import ALL, area_square, cross, make_topology, parallel
from topology.raw import PEDESTRIAN, VEHICLE


def _degenerate():
    """A street with a zero-length edge (B to B2 at one point), a bent edge with a repeated vertex (a
    zero-length segment), and a parallel footway 6 m away in three segments."""
    nodes = {"A": (0.0, 0.0), "B": (40.0, 0.0), "B2": (40.0, 0.0), "C": (120.0, 0.0),
             "F": (0.0, 6.0), "G": (120.0, 6.0), "H": (60.0, -30.0)}
    edges = [("A", "B"), ("B", "B2"), ("B2", "C", ALL, [(80.0, 0.0), (80.0, 0.0), (100.0, 2.0)]),
             ("F", "G", PEDESTRIAN, [(30.0, 6.5), (70.0, 5.5)]), ("B2", "H")]
    return make_topology(nodes, edges, junction_radius=5.0, street_cell_max=15.0)


def _way_cells_reference(placer, x, y, dx, dy, r, back, ahead, skip, only):
    """The candidate loop of `Coverage._lateral_cells` as written before the per-edge tables."""
    net = placer.net
    out = []
    for e in placer.edges_near(x, y, r):
        if e in skip or (only is not None and e not in only):
            continue
        f = placer.project_on(x, y, e)
        if f.distance > r:
            continue
        hx0, hy0 = net.point(e, min(f.offset + 1.0, net.edge_len[e]))
        bx0, by0 = net.point(e, max(f.offset - 1.0, 0.0))
        fwd = ((hx0 - bx0) * dx + (hy0 - by0) * dy) >= 0.0
        length = net.edge_len[e]
        lo, hi = (f.offset - back, f.offset + ahead) if fwd else (f.offset - ahead, f.offset + back)
        lo, hi = max(lo, 0.0), min(hi, length)
        for a0, b0, c in net.pieces(e, 1):
            if b0 >= lo and a0 <= hi and c not in out:
                out.append(c)
    return out


def _points(net, rng):
    """Random points, every geometry vertex (nodes included), points on edges at their cell boundaries."""
    pts = [(rng.uniform(-60.0, 180.0), rng.uniform(-60.0, 60.0)) for _ in range(300)]
    pts += list(zip(net.gx, net.gy, strict=True))
    for e in range(net.n_edges):
        for a0, _b0, _c in net.pieces(e, 1):
            pts.append(net.point(e, a0))
    return pts


@pytest.mark.parametrize("topo", [_degenerate(), cross(arm=100.0, street_cell_max=15.0), parallel(gap=6.0),
                                  area_square()])
def test_way_cells_equal_the_per_candidate_projection(topo):
    net = netview(topo)
    rng = random.Random(22)
    for networks in (PEDESTRIAN, VEHICLE):
        placer = Placer(net, networks)
        idx = near_index(placer)
        for x, y in _points(net, rng):
            for r in (0.0, 6.0, 10.0, 12.5, 80.0):
                ang = rng.uniform(0.0, 2.0 * math.pi)
                dx, dy = rng.choice([(math.cos(ang), math.sin(ang)), (0.0, 0.0), (1.0, 0.0), (0.0, -1.0)])
                back, ahead = rng.choice([(5.0, 30.0), (0.0, 0.0), (45.0, 45.0)])
                skip = set(rng.sample(range(net.n_edges), rng.randint(0, 2)))
                only = rng.choice([None, frozenset({0, 2}), frozenset()])
                want = _way_cells_reference(placer, x, y, dx, dy, r, back, ahead, skip, only)
                got = idx.way_cells(x, y, dx, dy, r, back, ahead, skip, only)
                assert got == want, (x, y, r, dx, dy, back, ahead, skip, only)


def test_way_cells_at_the_exact_reach_of_a_parallel_way():
    """A way exactly `r` away is a candidate (distance <= r), one a hair further is not."""
    net = netview(parallel(gap=6.0))
    idx = near_index(Placer(net, VEHICLE))
    on = idx.way_cells(150.0, 0.0, 1.0, 0.0, 6.0, 5.0, 30.0, {0}, None)
    off = idx.way_cells(150.0, 0.0, 1.0, 0.0, math.nextafter(6.0, 0.0), 5.0, 30.0, {0}, None)
    assert on and on == _way_cells_reference(Placer(net, VEHICLE), 150.0, 0.0, 1.0, 0.0, 6.0, 5.0, 30.0, {0}, None)
    assert not off


def test_edges_between_equals_the_scan():
    net = netview(_degenerate())
    rng = random.Random(5)
    for edges in ([(0, 1), (1, 1), (2, 1)], [(2, -1), (1, -1), (0, -1)], [(4, -1), (2, 1)], [(1, 1)]):
        path = Path(net, edges)
        cum = path.cum
        bounds = [rng.uniform(-20.0, path.length + 20.0) for _ in range(60)] + list(cum) + [math.nan]
        for lo in bounds:
            for hi in bounds[::7] + [lo]:
                want = {edges[k][0] for k in range(len(edges)) if cum[k + 1] >= lo and cum[k] <= hi}
                assert _edges_between(path, lo, hi) == want, (edges, lo, hi)


def test_within_ring_of_a_large_ring_equals_ring_distance():
    """A ring of 120 segments (a park or a square) and one of 3, both at their exact distances."""
    from entitynet.client.placement import ring_distance

    for n in (120, 3):
        ring = [(40.0 * math.cos(2 * math.pi * i / n), 30.0 * math.sin(2 * math.pi * i / n)) for i in range(n)]
        ring.append(ring[0])
        topo = make_topology({"Q": (0.0, 0.0), "W": (-140.0, 0.0)}, [("W", "Q", PEDESTRIAN)],
                             areas=[("Q", ring, PEDESTRIAN)], junction_radius=40.0)
        placer = Placer(netview(topo), PEDESTRIAN)
        idx = near_index(placer)
        rng = random.Random(n)
        pts = [(rng.uniform(-70.0, 70.0), rng.uniform(-60.0, 60.0)) for _ in range(400)] + ring + [(0.0, 0.0)]
        segs = idx._ring_segs(0)
        for x, y in pts:
            d = ring_distance(placer.ring(0), x, y)
            for r in (d, math.nextafter(d, 0.0), math.nextafter(d, math.inf), 0.0, 10.0):
                assert idx.within_ring(0, x, y, r) == (d <= r), (n, x, y, r)
            if lateral._COMPILED is not None:  # the compiled nearest segment is the pure one, bit for bit
                assert lateral._COMPILED.ring_nearest(segs, x, y) == lateral._ring_nearest_py(segs, x, y)


@pytest.mark.parametrize("topo", [_degenerate(), cross(arm=100.0, street_cell_max=15.0), parallel(gap=6.0),
                                  area_square()])
def test_the_compiled_candidate_loop_equals_the_pure_one(topo):
    """The C tables' loop (`WayTable.edges_cells` and, with the widened bucket's box test, `way_cells`; compiled
    where pip built them) gives what the pure loop `_way_cells_py` and the box test give, for every candidate of
    every edge, at random points, vertices and cell boundaries, with and without `skip` / `only`, and a direction
    or none."""
    from entitynet.client import lateral

    if lateral._WayTable is None:
        pytest.skip("the compiled candidate loop is not built here (the pure one is in use)")
    net = netview(topo)
    rng = random.Random(7)
    for networks in (PEDESTRIAN, VEHICLE):
        idx = near_index(Placer(net, networks))
        every = list(idx._ways.values())
        for x, y in _points(net, rng):
            for r in (0.0, 6.0, 12.5, 80.0):
                ang = rng.uniform(0.0, 2.0 * math.pi)
                dx, dy = rng.choice([(math.cos(ang), math.sin(ang)), (0.0, 0.0)])
                back, ahead = rng.choice([(5.0, 30.0), (0.0, 0.0)])
                skip = set(rng.sample(range(net.n_edges), rng.randint(0, 2)))
                only = rng.choice([None, frozenset({0, 2})])
                args = (x, y, dx, dy, r, back, ahead, skip, only)
                table = idx._waytable()
                assert table.edges_cells([w.edge for w in every], *args) == lateral._way_cells_py(every, *args)
                if r <= lateral.WIDE:
                    rows = idx.wide.get((math.floor(x / lateral.WIDE_SIZE), math.floor(y / lateral.WIDE_SIZE)), ())
                    box = (x - r, y - r, x + r, y + r)
                    cand = [w for _e, bx0, by0, bx1, by1, w in rows
                            if not (bx0 > box[2] or bx1 < box[0] or by0 > box[3] or by1 < box[1])]
                    key = (math.floor(x / lateral.WIDE_SIZE), math.floor(y / lateral.WIDE_SIZE))
                    assert table.way_cells(key, *args) == lateral._way_cells_py(cand, *args)


@pytest.mark.parametrize("topo", [_degenerate(), cross(arm=100.0, street_cell_max=15.0), parallel(gap=6.0)])
def test_the_compiled_path_point_equals_the_pure_one(topo):
    """`Path.xy` (compiled `_geom.path_xy` where pip built it) gives the pure method's point, bit for bit, on
    every edge both ways and on paths of several edges: at random coordinates, at every vertex and cell boundary,
    at the path's ends and beyond them, and at NaN and infinities."""
    from entitynet.client import path as path_mod

    if path_mod._COMPILED is None:
        pytest.skip("the compiled path point is not built here (the pure one is in use)")
    net = netview(topo)
    rng = random.Random(5)
    paths = [Path(net, [(e, d)]) for e in range(net.n_edges) for d in (1, -1)]
    for p in list(paths):  # and every path of two or three edges the junction rule follows
        for _ in range(2):
            from entitynet.client.path import follow
            more = follow(net, p.edges[-1], ALL, rng.uniform(0.0, 150.0), max_edges=2)
            if more:
                paths.append(p.extended(more))
    for p in paths:
        coords = [rng.uniform(-5.0, p.length + 5.0) for _ in range(40)] + list(p.cum)
        coords += [0.0, p.length, -0.0, math.nextafter(p.length, math.inf), math.inf, -math.inf, math.nan]
        for k, (e, d) in enumerate(p.edges):
            for a0, _b0, _c in net.pieces(e, d):
                coords.append(p.cum[k] + a0)
        for s in coords:
            got, want = p.xy(s), path_mod.xy_reference(p, s)
            assert [v if v == v else "nan" for v in got] == [v if v == v else "nan" for v in want], (p, s)
            assert all(type(v) is float for v in got)


def _same(fn, *args):
    """fn's answer with each float as its bit pattern (NaN as "nan"), or the exception's type."""
    try:
        out = fn(*args)
    except (ArithmeticError, ValueError) as exc:
        return type(exc).__name__
    if isinstance(out, float):
        out = [out]
    return ["nan" if v != v else struct.pack("=d", v) if isinstance(v, float) else v for v in out]


def test_the_compiled_kernels_equal_the_pure_ones_on_hard_inputs():
    """The three lateral / path kernels against their pure references where the random tests do not go: NaN,
    infinities, -0.0, subnormals and huge values as position, direction, radius, reach and path coordinate, and
    ring segments of zero, tiny and infinite length; compared by bit pattern (-0.0 is not 0.0 here)."""
    from entitynet.client import path as path_mod

    if lateral._COMPILED is None or lateral._WayTable is None or path_mod._COMPILED is None:
        pytest.skip("the compiled kernels are not built here (the pure ones are in use)")
    hard = [0.0, -0.0, 5e-324, 1e-300, 1e16, -1e16, 1e308, -1e308, math.inf, -math.inf, math.nan]
    rng = random.Random(11)
    net = netview(_degenerate())
    idx = near_index(Placer(net, ALL))
    every = list(idx._ways.values())
    pts = _points(net, rng)

    def pick(normal):
        return rng.choice(hard) if rng.random() < 0.4 else normal

    for _ in range(1500):
        x, y = rng.choice(pts) if rng.random() < 0.7 else (rng.choice(hard), rng.choice(hard))
        args = (x, y, pick(1.0), pick(-0.5), pick(12.5), pick(5.0), pick(30.0), set(), rng.choice([None, {0, 2}]))
        assert (_same(idx._waytable().edges_cells, [w.edge for w in every], *args)
                == _same(lateral._way_cells_py, every, *args)), args
        segs = tuple((pick(rng.uniform(-50, 50)), pick(rng.uniform(-50, 50)), pick(3.0), pick(-4.0),
                      rng.choice([25.0, 1e-300, 5e-324, math.inf, 1e308])) for _ in range(rng.randint(0, 3)))
        assert (_same(lateral._COMPILED.ring_nearest, segs, x, y)
                == _same(lateral._ring_nearest_py, segs, x, y)), (segs, x, y)
    paths = [Path(net, [(e, d)]) for e in range(net.n_edges) for d in (1, -1)]
    for p in paths:
        for s in hard + [-1e-320, math.nextafter(p.length, 0.0)] + list(p.cum):
            assert _same(p.xy, s) == _same(path_mod.xy_reference, p, s), (p, s)


def test_the_compiled_path_point_on_malformed_geometry_answers_as_the_pure_one():
    """An edge of one geometry point or none (a malformed artifact: the builder never makes one) at NaN or beyond
    the data: the compiled `Path.xy` reads the lists as Python does (the same point, or the same IndexError), never
    memory outside them. In a child process: an out-of-bounds read could end it."""
    from entitynet.client import path as path_mod

    if path_mod._COMPILED is None:
        pytest.skip("the compiled path point is not built here (the pure one is in use)")
    code = (
        "import math\nfrom types import SimpleNamespace as N\nfrom entitynet.client import _geom\n"
        "from entitynet.client.path import xy_reference\n"
        "def ans(fn, *a):\n    try:\n        return repr(fn(*a))\n    except IndexError as e:\n"
        "        return 'IndexError'\n"
        "for off, gx, gcum in (([0, 1], [1.0], [0.0]), ([0, 0], [], []), ([0, 2, 3], [0.0, 9.0, 4.0], [0.0, 9.0, 0.0]),"
        " ([0, 2, 2], [0.0, 9.0], [0.0, 9.0])):\n"
        "    for e in range(len(off) - 1):\n"
        "        net = N(edge_len=[10.0] * 3, geom_off=off, gx=gx, gy=[2.0 * v for v in gx], gcum=gcum)\n"
        "        for d in (1, -1):\n"
        "            p = N(cum=[0.0, 10.0], edges=[(e, d)], net=net)\n"
        "            for s in (math.nan, -1.0, 0.0, 5.0, 10.0, 11.0, math.inf):\n"
        "                assert ans(_geom.path_xy, p, s) == ans(xy_reference, p, s), (off, e, d, s)\n"
        "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         cwd=str(FilePath(__file__).resolve().parents[3]))
    assert out.returncode == 0 and out.stdout.strip() == "ok", (out.returncode, out.stderr[-2000:])
