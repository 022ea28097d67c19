"""The client core's fast paths give exactly (bit for bit) what the straightforward code gives.

Each fast path is checked against a reference: the numpy pass it replaces, or the previous plain code kept
here verbatim. Exact equality, not closeness: players and receivers must take the same decisions.
"""

import dataclasses
import math
from bisect import bisect_right

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet.client import netview
from entitynet.client.filters import Kinematic1D
from entitynet.client.frozen import maker
from entitynet.client.kinematics import advance
from entitynet.client.limits import HORIZON
from entitynet.client.motion import AreaModel, NetworkModel, WorldModel, network_model
from entitynet.client.occupation import (
    Occupation,
    _branch_cover,
    branch_cover,
    certain_end,
    choice_node,
    make_occupation,
)
from entitynet.client.path import Path
from entitynet.client.payload import (
    PayloadError,
    _encode_network_checked,
    encode,
    encode_network,
    encode_quantized,
    quantized,
)
from entitynet.client.placement import Fix, Placer, _ring_distance_np, _SegTable, ring_distance
from entitynet.client.player import Player
from entitynet.client.route import Route
from entitynet.protocol import Publish
from tests.entitynet.client_fixtures import area_square, chain, cross, hairpin, make_topology, parallel
from topology.raw import PEDESTRIAN, VEHICLE

TOPOS = [cross(arm=100.0), parallel(gap=12.0, length=300.0), chain(), hairpin(), area_square()]
NETS = [netview(t) for t in TOPOS]
coord = st.floats(-250.0, 350.0, allow_nan=False)


def _project_on_reference(net, x, y, edge):
    """The projection as it was written before the per-edge segment table."""
    lo, hi = net.geom_off[edge], net.geom_off[edge + 1]
    best = (math.inf, 0.0, 0.0, 0.0)
    for k in range(lo, hi - 1):
        ax, ay = net.gx[k], net.gy[k]
        dx, dy = net.gx[k + 1] - ax, net.gy[k + 1] - ay
        l2 = dx * dx + dy * dy
        u = 0.0 if l2 <= 0.0 else min(max(((x - ax) * dx + (y - ay) * dy) / l2, 0.0), 1.0)
        px, py = ax + u * dx, ay + u * dy
        dd = math.hypot(x - px, y - py)
        if dd < best[0]:
            best = (dd, net.gcum[k] + u * (net.gcum[k + 1] - net.gcum[k]), px, py)
    return Fix("edge", edge, best[1], best[2], best[3], best[0])


@settings(max_examples=150, deadline=None)
@given(st.integers(0, len(TOPOS) - 1), coord, coord, st.data())
def test_near_loop_equals_the_numpy_pass(ti, x, y, data):
    net = NETS[ti]
    networks = PEDESTRIAN if ti == 4 else VEHICLE
    pl = Placer(net, networks)
    edges = [e for e in range(net.n_edges) if net.edge_net[e] & networks]
    edge = data.draw(st.sampled_from(edges))
    preferred = set(data.draw(st.lists(st.sampled_from(edges), max_size=3)))
    margin = data.draw(st.sampled_from([None, 0.0, 3.0, 15.0]))
    t = pl.table(edge)
    got = pl._near_py(t, x, y, preferred, pl.switch_margin if margin is None else margin)
    want = pl._near_np(t, x, y, preferred, margin)
    assert got == want
    assert pl.project_on(x, y, edge) == _project_on_reference(net, x, y, edge)


def _star_area():
    """An irregular (star-shaped, non-convex) pedestrian area: slanted ring edges, a vertex on an integer y."""
    rng = np.random.default_rng(5)
    ring = [(r * math.cos(a), r * math.sin(a))
            for a, r in zip(np.linspace(0.0, 2 * math.pi, 12, endpoint=False), rng.uniform(20.0, 70.0, 12),
                            strict=True)]
    ring[3] = (ring[3][0], 30.0)
    ring.append(ring[0])
    nodes = {"Q": (0.0, 0.0), "W": (-200.0, 0.0)}
    return make_topology(nodes, [("W", "Q", PEDESTRIAN)], areas=[("Q", ring, PEDESTRIAN)], junction_radius=10.0)


AREA_NETS = [NETS[4], netview(_star_area())]


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 1), st.one_of(st.floats(-80.0, 80.0, allow_nan=False), st.integers(-80, 80).map(float)),
       st.one_of(st.floats(-80.0, 80.0, allow_nan=False), st.integers(-80, 80).map(float), st.just(30.0)))
def test_inside_area_box_test_agrees_with_the_crossing_count(ai, x, y):
    """The box test and the plain loop over the ring's edges give the numpy crossing count's answer (vertices
    on integer coordinates, slanted edges)."""
    net = AREA_NETS[ai]
    pl = Placer(net, PEDESTRIAN)
    r = pl.ring(0)
    x0, y0, x1, y1 = r[:-1, 0], r[:-1, 1], r[1:, 0], r[1:, 1]
    cond = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    assert pl.inside_area(0, x, y) == bool(np.count_nonzero(cond & (x < xs)) % 2)


@settings(max_examples=150, deadline=None)
@given(st.floats(0.0, 50.0), st.floats(-3.0, 3.0), st.booleans(),
       st.lists(st.tuples(st.floats(0.01, 3.0), st.floats(-100.0, 100.0)), min_size=1, max_size=8))
def test_filter_update_equals_predict_then_update(s0, v0, accel, steps):
    a = Kinematic1D(s0, 0.0, 25.0, q=0.3, accel=accel)
    b = Kinematic1D(s0, 0.0, 25.0, q=0.3, accel=accel)
    t = 0.0
    for dt, z in steps:
        t += dt
        ya = a.update(z, t, 25.0)
        # reference: the prediction step, then the measurement step as written before the inlining
        b.predict(t)
        yb = z - b.s
        p00, p01, p02 = b.p00, b.p01, b.p02
        sden = p00 + 25.0
        k0, k1, k2 = p00 / sden, p01 / sden, p02 / sden
        b.s += k0 * yb
        b.v += k1 * yb
        b.a += k2 * yb
        b.p11 -= k1 * p01
        b.p12 -= k1 * p02
        b.p22 -= k2 * p02
        b.p00 -= k0 * p00
        b.p01 -= k0 * p01
        b.p02 -= k0 * p02
        assert ya == yb
        assert [getattr(a, f) for f in Kinematic1D.__slots__] == [getattr(b, f) for f in Kinematic1D.__slots__]


def test_branch_cover_memo_returns_the_computed_tree_and_a_private_list():
    net = NETS[0]
    path = Path(net, [(0, 1)])
    cells, shortest = branch_cover(path, 0, 40.0, VEHICLE)
    assert (cells, shortest) == _branch_cover(net, (0, 1), 40.0, VEHICLE, 48, 64)
    cells.append(-7)  # the caller may extend its list: the cached tree must not change
    assert branch_cover(path, 0, 40.0, VEHICLE) == _branch_cover(net, (0, 1), 40.0, VEHICLE, 48, 64)
    assert branch_cover(path, 0, 10.0, VEHICLE) == _branch_cover(net, (0, 1), 10.0, VEHICLE, 48, 64)


finite = st.floats(-1e5, 1e5, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1e6), finite, finite, finite, st.floats(0.0, 40.0), st.one_of(st.just(math.inf), finite),
       st.lists(st.floats(0.0, 30.0), max_size=2), finite, finite)
def test_encode_quantized_equals_encode_of_quantized(t0, s0, v, a, vmax, stop_s, parts, x, y):
    path = Path(NETS[0], [(0, 1), (1, 1)])
    models = [NetworkModel(t0, path, s0, v, a, vmax, 3, tuple(parts), stop_s, 1.2),
              AreaModel(t0, 0, x, y, v, a, 0), WorldModel(t0, x, y, v, a, s0, vmax, 1)]
    for m in models:
        payload, ghost = encode_quantized(m)
        assert payload == encode(quantized(m))
        assert ghost == quantized(m)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, len(TOPOS) - 1),
       st.one_of(coord, st.integers(-250, 350).map(float)), st.one_of(coord, st.integers(-250, 350).map(float)),
       st.one_of(st.floats(0.0, 120.0), st.integers(0, 60).map(float)))
def test_edges_and_areas_near_equal_the_index_queries(ti, x, y, r):
    """Box hits, touching boxes included (integer coordinates make the box meet the streets exactly)."""
    net = NETS[ti]
    for networks in (PEDESTRIAN, VEHICLE, PEDESTRIAN | VEHICLE):
        pl = Placer(net, networks)
        assert pl.edges_near(x, y, r) == pl._edges_near_tree(x, y, r)
        bounds = net.topo.area_polygons.bounds()
        ok = (net.topo.area_networks & networks) != 0 if len(bounds) else np.zeros(0, bool)
        want = [] if not len(bounds) else np.flatnonzero(
            ok & (bounds[:, 0] - r <= x) & (x <= bounds[:, 2] + r) & (bounds[:, 1] - r <= y)
            & (y <= bounds[:, 3] + r)).tolist()
        assert pl.areas_near(x, y, r) == want


@settings(max_examples=150, deadline=None)
@given(st.floats(0.0, 1e5), st.floats(0.0, 200.0), st.floats(0.0, 40.0),
       st.one_of(st.just(math.inf), st.floats(-50.0, 300.0)), st.floats(0.1, 3.0),
       st.lists(st.floats(-10.0, 1e4), min_size=1, max_size=6))
def test_a_standing_network_ghost_answers_the_same_at_every_time(t0, s0, vmax, stop_s, brake, ts):
    """The premise of the player's cache of a standing ghost (v = a = 0): its answer does not depend on t."""
    g = NetworkModel(t0, Path(NETS[0], [(0, 1), (1, 1)]), s0, 0.0, 0.0, vmax, 3, (), stop_s, brake)
    first = g.xy_speed_at(t0)
    assert all(g.xy_speed_at(t0 + dt) == first for dt in ts)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_one_pass_cover_equals_cells_between_then_starts_in(f0, f1, f2):
    """`occupy`'s single pass over the path gives the cells of the two passes it replaced."""
    net = NETS[2]  # the chain: many short cells in a row
    path = Path(net, [(e, 1) for e in range(net.n_edges)])
    start, reach, cover_end = sorted(round(f * path.length, 1) for f in (f0, f1, f2))
    for a, b, c in ((start, reach, cover_end), (start, start, reach), (start, reach, reach)):
        want = path.cells_between(a, b)
        for sa, cell in path.starts_in(b, c):
            if sa < c and cell not in want:
                want.append(cell)
        got = [path.cell(a)]
        for sa, cell in path.starts_in(a, max(b, c)):
            if (sa <= b or sa < c) and cell not in got:
                got.append(cell)
        assert got == want


def _near_py_reference(t, x, y, preferred, margin):
    """`Placer._near_py` as it was written before it skipped far edges (every segment, in table order)."""
    sqrt = math.sqrt
    best_cost = best_pref = math.inf
    best = -1
    bu = bd = 0.0
    for k, (ax, ay, dx, dy, il2, e) in enumerate(t.rows):
        rx = x - ax
        ry = y - ay
        u = (rx * dx + ry * dy) * il2
        u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
        ex = rx - u * dx
        ey = ry - u * dy
        d = sqrt(ex * ex + ey * ey)
        if preferred and e in preferred:
            cost = d
            if d < best_pref:
                best_pref = d
        else:
            cost = d + margin if preferred else d
        if cost < best_cost:
            best_cost, best, bu, bd = cost, k, u, d
    if best < 0:
        return None
    ax, ay, dx, dy, _il2, e = t.rows[best]
    return Fix("edge", e, t.cum0_py[best] + bu * t.slen_py[best], ax + bu * dx, ay + bu * dy, bd), best_pref


def _mesh():
    """A jittered 5 x 5 street grid with bent edges: neighbourhood tables of many edges and segments."""
    rng = np.random.default_rng(11)
    nodes = {f"n{i}{j}": (i * 40.0 + rng.uniform(-8, 8), j * 40.0 + rng.uniform(-8, 8))
             for i in range(5) for j in range(5)}
    edges = []
    for i in range(5):
        for j in range(5):
            for di, dj in ((1, 0), (0, 1)):
                if i + di < 5 and j + dj < 5:
                    a, b = nodes[f"n{i}{j}"], nodes[f"n{i + di}{j + dj}"]
                    mids = [((a[0] + b[0]) / 2 + rng.uniform(-6, 6), (a[1] + b[1]) / 2 + rng.uniform(-6, 6))
                            for _ in range(int(rng.integers(0, 3)))]
                    mids.sort(key=lambda p, a=a: math.hypot(p[0] - a[0], p[1] - a[1]))
                    edges.append((f"n{i}{j}", f"n{i + di}{j + dj}", VEHICLE | PEDESTRIAN, mids))
    edges.append(("n00", "n11", VEHICLE | PEDESTRIAN))  # a diagonal crossing other edges' boxes
    return make_topology(nodes, edges)


MESH = netview(_mesh())


@settings(max_examples=200, deadline=None)
@given(st.integers(0, len(TOPOS)), st.data())
def test_near_skipping_far_edges_equals_the_full_loop(ti, data):
    """The pruned neighbourhood loop gives the full loop's answer bit for bit (ties, margins, no preferred)."""
    net = NETS[ti] if ti < len(TOPOS) else MESH
    networks = PEDESTRIAN if ti == 4 else VEHICLE
    pl = Placer(net, networks)
    edges = [e for e in range(net.n_edges) if net.edge_net[e] & networks]
    edge = data.draw(st.sampled_from(edges))
    t = pl.table(edge)
    tab_edges = t.edges
    preferred = set(data.draw(st.lists(st.sampled_from(tab_edges), max_size=5)))
    if data.draw(st.booleans()):
        preferred.add(edge)
    margin = data.draw(st.sampled_from([0.0, 3.0, 15.0]))
    # points near the table's vertices (on them, on segments, integer offsets) and anywhere around it
    k = data.draw(st.integers(0, len(t.rows) - 1))
    ax, ay, dx, dy = t.rows[k][:4]
    f = data.draw(st.one_of(st.just(0.0), st.just(0.5), st.just(1.0), st.floats(-0.5, 1.5)))
    off = data.draw(st.one_of(st.just(0.0), st.integers(-20, 20).map(float), st.floats(-60.0, 60.0)))
    x = ax + f * dx + off
    y = ay + f * dy + data.draw(st.one_of(st.just(0.0), st.integers(-20, 20).map(float), st.floats(-60.0, 60.0)))
    want = _near_py_reference(t, x, y, preferred, margin)
    assert want is not None
    for hint in (edge, None, data.draw(st.sampled_from(tab_edges))):
        assert pl._near_py(t, x, y, preferred, margin, hint) == want


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1e6), finite, st.floats(-1e3, 1e3), st.floats(-1e3, 1e3), st.floats(0.0, 40.0),
       st.one_of(st.just(math.inf), finite), st.lists(st.floats(0.0, 30.0), max_size=2), st.floats(0.01, 5.0))
def test_fast_model_constructors_equal_the_dataclass_init(t0, s0, v, a, vmax, stop_s, parts, brake):
    path = Path(NETS[0], [(0, 1), (1, 1)])
    got = network_model(t0, path, s0, v, a, vmax, 3, tuple(parts), stop_s, brake)
    want = NetworkModel(t0, path, s0, v, a, vmax, 3, tuple(parts), stop_s, brake)
    assert got == want and repr(got) == repr(want) and type(got) is NetworkModel
    occ = make_occupation((1, 2), t0, s0, math.inf, v, a)
    assert occ == Occupation((1, 2), t0, s0, math.inf, v, a)
    pub = maker(Publish)(7, 2, (1, 2), 5, b"x")
    assert pub == Publish(7, 2, (1, 2), 5, b"x") and hash(pub) == hash(Publish(7, 2, (1, 2), 5, b"x"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        occ.validity = 1.0  # still frozen


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1e6), finite, finite, finite, st.floats(0.0, 40.0), st.one_of(st.just(math.inf), finite),
       st.lists(st.floats(0.0, 30.0), max_size=2), st.floats(0.01, 5.0))
def test_encode_network_equals_the_checked_encoder(t0, s0, v, a, vmax, stop_s, parts, brake):
    path = Path(NETS[0], [(0, 1), (1, 1)])
    args = (t0, path, s0, v, a, vmax, 3, tuple(parts), stop_s, brake)
    payload, ghost = encode_network(*args)
    want_payload, want_ghost = _encode_network_checked(*args)
    assert payload == want_payload and ghost == want_ghost and repr(ghost) == repr(want_ghost)
    for k in (0, 2, 3, 4, 5, 7, 9):  # a non-finite value raises as before (7: in the parts)
        for value in (math.nan, math.inf, -math.inf):
            bad = list(args)
            bad[k] = (*parts, value) if k == 7 else value
            if k == 3 and value == -math.inf:
                bad_payload, bad_ghost = encode_network(*bad)  # max(v, 0.0) makes a speed of -inf zero
                assert (bad_payload, bad_ghost) == _encode_network_checked(*bad)
                continue
            with pytest.raises(PayloadError):
                encode_network(*bad)
    huge = list(args)
    huge[2], huge[4] = 1e300, 1.7e308  # finite values whose sum overflows: the checked path, the same outcome
    with pytest.raises(OverflowError):  # (1.7e308 * 1000 is inf: round fails, before and now)
        _encode_network_checked(*huge)
    with pytest.raises(OverflowError):
        encode_network(*huge)


def _xy_reference(path, s):
    """`Path.xy` as it was: `locate`, then `NetView.point`."""
    e, off = path.locate(s)
    return path.net.point(e, off)


def _random_path(net, data, networks=VEHICLE | PEDESTRIAN):
    """A walk of up to 8 directed edges through `net` (any turn, U-turns excepted when there is a choice)."""
    edges = [e for e in range(net.n_edges) if net.edge_net[e] & networks]
    de = (data.draw(st.sampled_from(edges)), data.draw(st.sampled_from([1, -1])))
    out = [de]
    for _ in range(data.draw(st.integers(0, 7))):
        nxt = net.choices(out[-1], networks)
        if not nxt:
            break
        out.append(data.draw(st.sampled_from(nxt)))
    return Path(net, out)


@settings(max_examples=100, deadline=None)
@given(st.integers(0, len(TOPOS)), st.data())
def test_path_xy_equals_locate_then_point(ti, data):
    net = NETS[ti] if ti < len(TOPOS) else MESH
    path = _random_path(net, data)
    for _ in range(5):
        s = data.draw(st.one_of(st.floats(-5.0, path.length + 5.0), st.sampled_from(path.cum),
                                st.sampled_from([-0.0, 0.0, path.length])))
        assert path.xy(s) == _xy_reference(path, s)


def _certain_end_reference(path, s_front, networks, known_until):
    """`certain_end` as it was written before the shared search."""
    net = path.net
    k = path.index(max(s_front, known_until))
    while k < len(path.edges):
        de = path.edges[k]
        s_node = path.cum[k + 1]
        if s_node >= known_until and s_node >= s_front and (
                len(net.choices(de, networks)) > 1 or net.node_area[net.end_node(de)] >= 0):
            node_cell = path.cell(s_node - 1e-9) if s_node > 0 else path.cell(0.0)
            allowance = math.inf
            for cand in net.choices(de, networks):
                pieces = net.pieces(*cand)
                a0, b0, c0 = pieces[0]
                allowance = min(allowance, b0 if c0 == node_cell else 0.0)
            if not net.choices(de, networks):
                allowance = 0.0
            return min(s_node + allowance, path.length)
        k += 1
    return path.length


def _choice_node_reference(path, s_front, networks, known_until):
    net = path.net
    k = path.index(max(s_front, known_until))
    while k < len(path.edges):
        s_node = path.cum[k + 1]
        de = path.edges[k]
        if s_node >= known_until and s_node >= s_front and (
                len(net.choices(de, networks)) > 1 or net.node_area[net.end_node(de)] >= 0):
            return k, s_node
        k += 1
    return None


@settings(max_examples=100, deadline=None)
@given(st.integers(0, len(TOPOS)), st.data())
def test_shared_choice_search_equals_the_two_loops(ti, data):
    net = NETS[ti] if ti < len(TOPOS) else MESH
    networks = data.draw(st.sampled_from([VEHICLE, PEDESTRIAN, VEHICLE | PEDESTRIAN]))
    path = _random_path(net, data)
    for _ in range(4):
        s = data.draw(st.one_of(st.floats(-5.0, path.length + 5.0), st.sampled_from(path.cum)))
        known = data.draw(st.one_of(st.just(0.0), st.floats(0.0, path.length + 5.0), st.sampled_from(path.cum)))
        assert certain_end(path, s, networks, known) == _certain_end_reference(path, s, networks, known)
        assert choice_node(path, s, networks, known) == _choice_node_reference(path, s, networks, known)


def _xy_speed_at_reference(g, t):
    """`NetworkModel.xy_speed_at` as it was: `_state` written out, `advance` called in every case (standing
    after the horizon)."""
    dt = t - g.t0
    if dt > HORIZON:
        x, y, _ = _xy_speed_at_reference(g, g.t0 + HORIZON)
        return x, y, 0.0
    tb, sb, vb, b = g.plan
    if dt <= tb:
        ds, v = advance(g.v, g.a, g.vmax, dt)
        s = g.s0 + ds
    elif not math.isfinite(b):
        s, v = sb, 0.0
    else:
        ds, v = advance(vb, -b, vb, dt - tb)
        s = min(sb + ds, g.stop_s)
    x, y = g.path.xy(min(s, g.path.cum[-1]))
    return x, y, v


@settings(max_examples=100, deadline=None)
@given(st.integers(0, len(TOPOS)), st.data(), st.floats(-50.0, 400.0), st.floats(0.0, 30.0),
       st.one_of(st.just(0.0), st.just(1e-10), st.just(-1e-10), st.floats(-3.0, 3.0)), st.floats(0.0, 30.0),
       st.one_of(st.just(math.inf), st.floats(-10.0, 400.0)), st.lists(st.floats(-5.0, 100.0), min_size=1, max_size=5))
def test_xy_speed_and_cells_written_out_equal_the_calls(ti, data, s0, v, a, vmax, stop_s, dts):
    net = NETS[ti] if ti < len(TOPOS) else MESH
    path = _random_path(net, data)
    g = NetworkModel(10.0, path, s0, v, a, vmax, 3, (4.0,), stop_s, 1.2)
    for dt in [0.0, *dts]:
        assert g.xy_speed_at(10.0 + dt) == _xy_speed_at_reference(g, 10.0 + dt)
    for _ in range(5):
        s = data.draw(st.one_of(st.floats(-5.0, path.length + 5.0), st.sampled_from(path.cum)))
        e, off = path.locate(s)
        assert path.cell(s) == net.cell_at(e, off)
        reach = s + data.draw(st.floats(0.0, 30.0))
        cover_end = data.draw(st.one_of(st.just(reach), st.floats(s, path.length + 10.0)))
        want = [path.cell(s)]  # `occupy`'s one pass as it was written with `starts_in`
        for sa, c in path.starts_in(s, max(reach, cover_end)):
            if (sa <= reach or sa < cover_end) and c not in want:
                want.append(c)
        assert path.cover_cells(s, reach, cover_end) == want


def _known_until_reference(r, path, s):
    """`Route.known_until` as it was (without its memo): walk the route pairs from the edge holding s."""
    if not r:
        return 0.0
    k = path.index(s)
    if path.edges[k] not in r.first:
        return 0.0
    edges, n = path.edges, len(path.edges)
    while k + 1 < n and (edges[k], edges[k + 1]) in r.pairs:
        k += 1
    return path.cum[k + 1]


@settings(max_examples=100, deadline=None)
@given(st.integers(0, len(TOPOS)), st.data())
def test_known_until_route_stretch_equals_the_pair_walk(ti, data):
    """Paths along the route, off it, or along a route that passes an edge twice (pairs from elsewhere)."""
    net = NETS[ti] if ti < len(TOPOS) else MESH
    route = _random_path(net, data).edges
    if data.draw(st.booleans()):
        route = route + _random_path(net, data).edges  # a second stretch (may not join: pairs only)
    r = Route(net, route)
    for _ in range(3):
        # the route's first stretch (a path along the route), or any walk (on and off the route)
        first = route[: len(route) if _joins(net, route) else 1]
        path = Path(net, first) if data.draw(st.booleans()) else _random_path(net, data)
        k = data.draw(st.integers(0, len(path.edges) - 1))
        sub = path.suffix(k)
        assert sub == Path(net, path.edges[k:]) and sub.cum == [c - path.cum[k] for c in path.cum[k:]]
        for s in (data.draw(st.floats(-5.0, sub.length + 5.0)), *sub.cum):
            r._ku_memo = None
            assert r.known_until(sub, s) == _known_until_reference(r, sub, s)


def _joins(net, edges):
    return all(net.end_node(a) == net.start_node(b) for a, b in zip(edges, edges[1:], strict=False))



@settings(max_examples=300, deadline=None)
@given(st.integers(0, 1), st.one_of(st.floats(-90.0, 90.0), st.integers(-90, 90).map(float)),
       st.one_of(st.floats(-90.0, 90.0), st.integers(-90, 90).map(float), st.just(30.0)))
def test_ring_distance_loop_equals_the_numpy_pass(ai, x, y):
    ring = Placer(AREA_NETS[ai], PEDESTRIAN).ring(0)
    assert ring_distance(ring, x, y) == _ring_distance_np(ring, x, y)
    dup = np.vstack([ring[:2], ring[1:]])  # a zero-length segment
    assert ring_distance(dup, x, y) == _ring_distance_np(dup, x, y)
    assert ring_distance(ring[:1], x, y) == _ring_distance_np(ring[:1], x, y) == math.inf


def _state(p):
    kf, tr = p.kf, p.tracker
    return (p.mode, p.path.edges if p.path else None, p.path.cum if p.path else None,
            [getattr(kf, f) for f in kf.FIELDS] if kf is not None else None, tr.last_fix, tr.pending,
            tr.dist_ema, list(tr.recent_s), tr.vpeak, tr.vpeak_t, tr.reverse_count, tr.dead_end, p.ghost,
            p.occupation)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, len(TOPOS)), st.sampled_from(["car", "pedestrian", "tram"]), st.booleans(),
       st.integers(0, 2**32 - 1), st.floats(0.5, 8.0), st.data())
def test_track_on_equals_the_general_track(ti, etype, with_route, seed, noise, data):
    """Walk a random path (forwards, pausing, turning back) with GPS noise: the players with and without
    `_track_on` send the same messages and hold the same state after every fix."""
    net = NETS[ti] if ti < len(TOPOS) else MESH
    path = _random_path(net, data)
    route = path.edges if with_route else None
    a = Player(net.topo, 1, etype, route=route, accuracy=5.0)
    b = Player(net.topo, 1, etype, route=route, accuracy=5.0)
    b.tracker.written_out = False  # every fix through `track`'s general code (what `_track_on` writes out)
    assert a.tracker.written_out
    rng = np.random.default_rng(seed)
    s, v = 0.0, float(rng.uniform(0.0, 12.0))
    for i in range(80):
        if rng.random() < 0.05:
            v = -v if rng.random() < 0.3 else float(rng.uniform(0.0, 12.0))
        s = min(max(s + v, 0.0), path.length)
        x, y = path.xy(s)
        x, y = x + float(rng.normal(0.0, noise)), y + float(rng.normal(0.0, noise))
        assert a.feed(x, y, float(i)) == b.feed(x, y, float(i))
        assert _state(a) == _state(b)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, len(TOPOS)), st.data())
def test_segment_table_rows_and_groups_equal_the_vertex_loop(ti, data):
    """The table built in one numpy pass holds the vertex loop's numbers (the loop it replaced, here verbatim),
    the rows the plain loop reads are the numpy arrays' numbers, and the groups are the loop's boxes and row
    ranges edge by edge."""
    net = NETS[ti] if ti < len(TOPOS) else MESH
    edges = data.draw(st.lists(st.integers(0, net.n_edges - 1), min_size=1, max_size=12))
    t = _SegTable(Placer(net, VEHICLE).geom, edges, [])
    ax, ay, dx, dy, cum0, eid = [], [], [], [], [], []
    for e in sorted(set(edges)):
        for k in range(net.geom_off[e], net.geom_off[e + 1] - 1):
            ax.append(net.gx[k])
            ay.append(net.gy[k])
            dx.append(net.gx[k + 1] - net.gx[k])
            dy.append(net.gy[k + 1] - net.gy[k])
            cum0.append(net.gcum[k])
            eid.append(e)
    ax, ay, dx, dy = np.array(ax), np.array(ay), np.array(dx), np.array(dy)
    l2 = dx * dx + dy * dy
    inv_l2 = np.where(l2 > 0.0, 1.0 / np.where(l2 > 0.0, l2, 1.0), 0.0)
    for got, want in ((t.ax, ax), (t.ay, ay), (t.dx, dx), (t.dy, dy), (t.inv_l2, inv_l2), (t.slen, np.sqrt(l2)),
                      (t.cum0, np.array(cum0)), (t.edge, np.array(eid, dtype=np.int64))):
        assert got.dtype == want.dtype and got.tolist() == want.tolist()
    assert t.rows == list(zip(ax.tolist(), ay.tolist(), dx.tolist(), dy.tolist(), inv_l2.tolist(), eid, strict=True))
    assert t.slen_py == np.sqrt(l2).tolist() and t.cum0_py == cum0
    assert [g[0] for g in t.groups] == sorted(set(eid)) and all(t.rows[g[5]][5] == g[0] for g in t.groups)
    groups, k = [], 0
    while k < len(t.rows):  # (the loop that built the groups before)
        e, k1, xs, ys = t.rows[k][5], k, [], []
        while k1 < len(t.rows) and t.rows[k1][5] == e:
            rax, ray, rdx, rdy = t.rows[k1][:4]
            xs += (rax, rax + rdx)
            ys += (ray, ray + rdy)
            k1 += 1
        groups.append((e, min(xs), min(ys), max(xs), max(ys), k, k1))
        k = k1
    assert t.groups == groups and t.group_of == {g[0]: g for g in groups}


def _point_reference(net, edge, offset):
    """`NetView.point` as it was (a bisection for every edge)."""
    lo, hi = net.geom_off[edge], net.geom_off[edge + 1]
    cum = net.gcum
    if offset <= 0.0:
        return net.gx[lo], net.gy[lo]
    if offset >= cum[hi - 1]:
        return net.gx[hi - 1], net.gy[hi - 1]
    k = bisect_right(cum, offset, lo, hi) - 1
    k = min(max(k, lo), hi - 2)
    seg = cum[k + 1] - cum[k]
    t = 0.0 if seg <= 0.0 else (offset - cum[k]) / seg
    x0, y0 = net.gx[k], net.gy[k]
    return x0 + t * (net.gx[k + 1] - x0), y0 + t * (net.gy[k + 1] - y0)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, len(TOPOS)), st.data())
def test_point_one_segment_shortcut_equals_the_bisection(ti, data):
    net = NETS[ti] if ti < len(TOPOS) else MESH
    e = data.draw(st.integers(0, net.n_edges - 1))
    for off in (data.draw(st.floats(-5.0, net.edge_len[e] + 5.0)), 0.0, net.edge_len[e], net.edge_len[e] / 2):
        assert net.point(e, off) == _point_reference(net, e, off)
