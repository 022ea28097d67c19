"""Planned halts at known stops, standing entities under noise, parallel ways, route-first placement."""

import math
import random

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from entitynet.client import NetworkModel, Path, Player, decode, encode, netview
from entitynet.client.kinematics import brake_plan
from entitynet.client.limits import HORIZON
from tests.entitynet.client_fixtures import cross, parallel


@given(v=st.floats(0.0, 20.0), a=st.floats(-2.0, 2.0), vmax=st.floats(1.0, 20.0), d=st.floats(0.5, 500.0),
       b=st.floats(0.3, 3.0))
@example(v=4.0, a=1e-9, vmax=5.0, d=15.0, b=2.0)  # a tiny acceleration: the quadratic must not cancel
@settings(max_examples=300, deadline=None)
def test_a_planned_halt_stops_exactly_at_the_stop_and_time_to_inverts_s_at(v, a, vmax, d, b):
    net = netview(cross(arm=600.0))
    path = Path(net, [(0, 1), (1, 1)])
    m = NetworkModel(0.0, path, 50.0, v, a, vmax, 3, (), 50.0 + d, b)
    far = m.s_at(1e6)
    assert far <= 50.0 + d + 1e-6  # never passes the stop
    tb, sb, vb, be = m.plan
    assert (tb, be) == brake_plan(v, a, vmax, (50.0 + d) - 50.0, b) or not math.isfinite(tb)
    if math.isfinite(tb) and tb + vb / be + 1.0 <= HORIZON and math.isfinite(be):  # (models stand at the horizon)
        assert m.s_at(tb + vb / be + 1.0) == pytest.approx(50.0 + d, abs=1e-6)  # halts exactly there
    for frac in (0.1, 0.5, 0.9):
        target = frac * (far - 50.0)
        t = m.time_to(target)
        if math.isfinite(t):
            assert m.s_at(t) == pytest.approx(50.0 + target, abs=1e-5)


def test_player_publishes_the_next_known_stop_and_the_ghost_halts_there():
    topo = cross(arm=600.0)
    route = [(0, 1), (1, 1)]
    p = Player(topo, 1, "tram", route=route, stops=[(0, 550.0), (1, 150.0)], threshold=5.0)
    for i in range(30):
        p.feed(-590.0 + 9.0 * i, 0.0, float(i))
    g = p.ghost
    assert g.v > 0 and math.isfinite(g.stop_s)
    assert g.xy_at(g.t0 + 600.0) == pytest.approx((-50.0, 0.0), abs=0.05)
    back = decode(encode(g), netview(topo))
    assert back.stop_s == g.stop_s and back.xy_at(g.t0 + 50.0) == g.xy_at(g.t0 + 50.0)


def test_a_standing_entity_under_gps_noise_sends_almost_nothing():
    rnd = random.Random(3)
    p = Player(cross(arm=300.0), 1, "bus", threshold=5.0)
    out = []
    for i in range(600):  # ten minutes standing, 5 m RMS noise
        out += p.feed(-100.0 + rnd.gauss(0, 3.54), rnd.gauss(0, 3.54), float(i))
        out += p.tick(i + 0.5)
    # first fix, heartbeats/validity renewals at most once a minute, and a few noise-driven corrections
    assert len(out) <= 25, p.stats
    assert p.ghost.xy_at(600.0) == pytest.approx((-100.0, 0.0), abs=5.0)


def test_lateral_cells_cover_the_parallel_way():
    topo = parallel(gap=8.0, length=400.0)  # two ways 8 m apart: GPS cannot tell them apart
    net = netview(topo)
    p = Player(topo, 1, "pedestrian", threshold=5.0)
    (m,) = p.feed(200.0, 1.0, 0.0)
    south, north = net.cell_at(0, 200.0), net.cell_at(1, 200.0)
    assert south in m.cells and north in m.cells
    q = Player(topo, 2, "pedestrian", threshold=5.0, lateral=0.0)
    (m2,) = q.feed(200.0, 1.0, 0.0)
    assert north not in m2.cells


def test_first_fix_prefers_the_route_over_a_slightly_nearer_street():
    topo = parallel(gap=10.0, length=400.0)
    p = Player(topo, 1, "bus", route=[(1, 1)], threshold=5.0)  # the route runs on the northern way
    p.feed(100.0, 4.0, 0.0)  # 4 m from the southern way, 6 m from the route
    assert p.inferred[1] == 1
    q = Player(topo, 2, "bus", threshold=5.0)
    q.feed(100.0, 4.0, 0.0)
    assert q.inferred[1] == 0
