"""Cell occupation and validity periods, including the reference's two-tram example (figure 3)."""

import math

import pytest

from entitynet.client import Path, netview, occupy
from tests.entitynet.client_fixtures import chain, cross, make_topology
from topology.raw import TRAM

V = 10.0  # m/s
TRAM_LEN = 30.0  # a two-part tram, 2 x 15 m


@pytest.fixture
def x_crossing():
    # X crossing at the origin, arms 100 m, the X-shaped junction cell reaches 20 m along every arm
    topo = cross(arm=100.0, junction_radius=20.0)
    net = netview(topo)
    path = Path(net, [(0, 1), (1, 1)])  # west -> centre -> east, straight across
    return topo, net, path


def cell_names(net, path):
    west, x, east = path.cell(10.0), path.cell(100.0), path.cell(190.0)
    assert net.is_junction_cell(x) and not net.is_junction_cell(west)
    return west, x, east


def test_reference_two_tram_example(x_crossing):
    _topo, net, path = x_crossing
    west, x, _east = cell_names(net, path)
    # Tram A: its front has just entered the X cell (1 m in); the route is known: straight across.
    a = occupy(path, 81.0, TRAM_LEN, V, 0.0, 14.0, TRAM, known_until=path.length)
    assert a.cells == (west, x)  # until the period expires the tram occupies two cells
    assert a.front_period == pytest.approx((120.0 - 81.0) / V)  # front: to the far side of the X cell
    assert a.aft_period == pytest.approx((80.0 - 51.0) / V)  # aft: leaving the street cell
    assert a.front_period > a.aft_period
    assert a.validity == pytest.approx(a.aft_period)  # the aft period is selected
    # Tram B: positioned before its period expired, caught before reaching the node: all of it in the X cell.
    b = occupy(path, 95.0, 14.0, V, 0.0, 14.0, TRAM, known_until=path.length)
    assert b.cells == (x,)
    assert b.front_period == pytest.approx((120.0 - 95.0) / V)
    assert b.aft_period == pytest.approx((120.0 - 81.0) / V)  # the aft must cross the whole X cell
    assert b.validity == pytest.approx(b.front_period)  # the front period is shorter and selected


def test_without_route_the_front_period_stops_where_any_branch_leaves_the_junction_cell():
    # T crossing whose south arm is short: its whole 6 m edge lies in the junction cell, then a dead end.
    nodes = {"C": (0.0, 0.0), "W": (-100.0, 0.0), "E": (100.0, 0.0), "S": (0.0, -6.0), "S2": (0.0, -106.0)}
    topo = make_topology(nodes, [("W", "C"), ("C", "E"), ("C", "S"), ("S", "S2")], junction_radius=20.0)
    net = netview(topo)
    path = Path(net, [(0, 1), (1, 1)])
    with_route = occupy(path, 81.0, 0.0, V, 0.0, 14.0, 7, known_until=path.length)
    no_route = occupy(path, 81.0, 0.0, V, 0.0, 14.0, 7, known_until=0.0)
    assert with_route.front_period == pytest.approx((120.0 - 81.0) / V)
    # the branch south changes cell after 6 m (S has degree 2 here: its own street cell)... or the min branch
    assert no_route.front_period < with_route.front_period
    assert no_route.cover_end <= 106.0 + 1e-9


def test_zero_speed_gives_unbounded_period_capped_on_the_wire(x_crossing):
    _topo, _net, path = x_crossing
    o = occupy(path, 50.0, 0.0, 0.0, 0.0, 14.0, 7, known_until=path.length, max_validity=60.0)
    assert math.isinf(o.front_period)
    assert o.validity == 60.0


def test_deceleration_stopping_before_the_boundary_has_no_real_root(x_crossing):
    _topo, _net, path = x_crossing
    # 10 m/s, -2 m/s^2 stops after 25 m; the boundary is 30 m ahead
    o = occupy(path, 50.0, 0.0, 10.0, -2.0, 14.0, 7, known_until=path.length, max_validity=45.0)
    assert math.isinf(o.front_period)
    assert o.validity == 45.0
    o2 = occupy(path, 56.0, 0.0, 10.0, -2.0, 14.0, 7, known_until=path.length)
    assert o2.front_period == pytest.approx(4.0)  # 24 m at 10 m/s, -2 m/s^2: t^2 - 10t + 24 = 0, t = 4


def test_lookahead_covers_cells_ahead_along_a_known_path(x_crossing):
    _topo, _net, path = x_crossing
    west, x, east = path.cell(10.0), path.cell(100.0), path.cell(190.0)
    o = occupy(path, 40.0, 0.0, V, 0.0, 14.0, 7, known_until=path.length, margin=5.0, lookahead=60.0)
    assert o.cells == (west, x)  # reach 45 + 60 = 105 lies in the X cell: covered to its end at 120
    assert o.cover_end == pytest.approx(120.0)
    assert o.front_period == pytest.approx((120.0 - 45.0) / V)
    assert math.isinf(o.aft_period)  # with a lookahead the cells behind are only over-coverage
    assert east not in o.cells


def test_margin_widens_the_body_on_both_sides(x_crossing):
    _topo, _net, path = x_crossing
    west, x, _e = path.cell(10.0), path.cell(100.0), path.cell(190.0)
    assert occupy(path, 77.0, 0.0, V, 0.0, 14.0, 7, known_until=path.length).cells == (west,)
    assert occupy(path, 77.0, 0.0, V, 0.0, 14.0, 7, known_until=path.length, margin=5.0).cells == (west, x)


def test_entity_longer_than_a_chain_of_short_cells():
    topo = chain(n=12, piece=3.0, lead=50.0)
    net = netview(topo)
    path = Path(net, [(e, 1) for e in range(topo.n_edges)])
    o = occupy(path, 50.0 + 36.0 + 10.0, TRAM_LEN, V, 0.0, 14.0, 7, known_until=path.length)
    # the body [66, 96] covers the last 6 short cells... every cell under it is listed once, in order
    expected = path.cells_between(66.0, 96.0)
    assert o.cells == tuple(expected)
    assert len(set(o.cells)) == len(o.cells) >= 5
    # the aft leaves its 3 m cell after 0.x s
    assert o.aft_period <= 3.0 / V + 1e-9


def test_junction_cells_back_to_back():
    # two crossings 15 m apart: the middle edge is split between the two junction cells, no street cell
    nodes = {"A": (0.0, 0.0), "B": (15.0, 0.0), "W": (-100.0, 0.0), "E": (115.0, 0.0),
             "AN": (0.0, 100.0), "AS": (0.0, -100.0), "BN": (15.0, 100.0), "BS": (15.0, -100.0)}
    edges = [("W", "A"), ("A", "B"), ("B", "E"), ("A", "AN"), ("A", "AS"), ("B", "BN"), ("B", "BS")]
    topo = make_topology(nodes, edges, junction_radius=10.0)
    net = netview(topo)
    path = Path(net, [(0, 1), (1, 1), (2, 1)])
    ja, jb = path.cell(100.0), path.cell(110.0)
    assert ja != jb and net.is_junction_cell(ja) and net.is_junction_cell(jb)
    assert path.boundaries_after(95.0, 130.0)[0] == (pytest.approx(107.5), jb)
    o = occupy(path, 105.0, 0.0, V, 0.0, 14.0, 7, known_until=path.length)
    assert o.cells == (ja,)
    assert o.front_period == pytest.approx(0.25)


def test_without_route_the_lookahead_covers_every_branch_of_the_next_junction():
    from tests.entitynet.client_fixtures import tee

    topo = tee(arm=100.0, junction_radius=10.0)  # edges 0: W->C, 1: C->E, 2: C->S
    net = netview(topo)
    path = Path(net, [(0, 1), (1, 1)])  # the junction rule predicts straight on
    o = occupy(path, 50.0, 0.0, V, 0.0, 14.0, 7, known_until=0.0, margin=5.0, lookahead=150.0)
    east, south = net.cell_at(1, 50.0), net.cell_at(2, 50.0)
    assert east in o.cells and south in o.cells  # a tree: both ways on are covered
    assert math.isinf(o.front_period)  # both branches covered to their dead ends: it cannot leave them
    shallow = occupy(path, 50.0, 0.0, V, 0.0, 14.0, 7, known_until=0.0, margin=5.0, lookahead=150.0,
                     branch_depth=5.0)
    assert east not in shallow.cells and south not in shallow.cells  # only the junction cell past the node
    assert shallow.cover_end == pytest.approx(110.0)  # where both branches leave the junction cell
    assert shallow.front_period == pytest.approx((110.0 - 55.0) / V)
    tight = occupy(path, 50.0, 0.0, V, 0.0, 14.0, 7, known_until=0.0, margin=5.0)
    assert south not in tight.cells and east not in tight.cells


def test_standing_in_an_area_near_its_boundary_keeps_the_area_cell_for_good():
    """Within the margin of the boundary a moving entity may leave at once, a standing one never does."""
    from entitynet.client.occupation import occupy_area

    ring = [(0.0, 0.0), (60.0, 0.0), (60.0, 60.0), (0.0, 60.0), (0.0, 0.0)]
    standing = occupy_area(1.0, 30.0, 0.0, 0.0, ring, 9, margin=5.0, max_validity=60.0)
    assert standing.cells == (9,) and standing.front_period == math.inf and standing.validity == 60.0
    moving = occupy_area(1.0, 30.0, 1.0, 0.0, ring, 9, margin=5.0, max_validity=60.0)
    assert moving.validity == 0.5  # the floor: it may already be outside
    inside = occupy_area(30.0, 30.0, 1.0, 0.0, ring, 9, margin=5.0, max_validity=60.0)
    assert inside.validity == pytest.approx(25.0)  # 30 m to the nearest boundary, less the margin, at 1 m/s
