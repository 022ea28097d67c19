"""Numerical stability: zero speeds, no-root decelerations, bad times, huge coordinates, long runs."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet.client import FixRejected, Player, advance, decode, encode, netview, time_to_travel
from entitynet.client.motion import NetworkModel
from entitynet.client.path import Path
from tests.entitynet.client_fixtures import chain, cross

speeds = st.floats(0.0, 40.0, allow_nan=False)
accels = st.floats(-5.0, 5.0, allow_nan=False)
dists = st.floats(0.0, 2000.0, allow_nan=False)


@given(d=dists, v=speeds, a=accels, vmax=st.floats(0.0, 40.0))
@settings(max_examples=300, deadline=None)
def test_time_to_travel_inverts_advance(d, v, a, vmax):
    t = time_to_travel(d, v, a, vmax)
    assert t >= 0.0 and not math.isnan(t)
    if math.isinf(t):
        # never: the motion stops (or never starts) before d
        far, _ = advance(v, a, vmax, 1e7)
        assert far <= d + 1e-6 * max(1.0, d)
    else:
        covered, _ = advance(v, a, vmax, t)
        assert covered == pytest.approx(d, rel=1e-6, abs=1e-6)


@given(v=st.floats(0.0, 1e-300), a=st.floats(-1e-300, 0.0))
def test_zero_and_near_zero_speed_give_an_unbounded_period(v, a):
    assert math.isinf(time_to_travel(10.0, v, a, 14.0)) or time_to_travel(10.0, v, a, 14.0) > 1e100


def test_deceleration_that_stops_before_the_boundary_has_no_root():
    assert math.isinf(time_to_travel(25.0 + 1e-9, 10.0, -2.0, 14.0))
    assert time_to_travel(25.0, 10.0, -2.0, 14.0) == pytest.approx(5.0)


@given(t=st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False))
def test_time_backwards_or_repeating_is_rejected(t):
    p = Player(cross(), 1, "pedestrian")
    p.feed(-50.0, 0.0, 1e6)
    with pytest.raises(FixRejected):
        p.feed(-49.0, 0.0, min(t, 1e6))


@given(x=st.sampled_from([math.nan, math.inf, -math.inf]))
def test_nan_and_inf_fixes_are_rejected(x):
    p = Player(cross(), 1, "pedestrian")
    with pytest.raises(FixRejected):
        p.feed(x, 0.0, 0.0)
    with pytest.raises(FixRejected):
        p.feed(0.0, x, 0.0)
    assert p.seq == 0


def test_utm_northings_keep_centimetre_precision():
    # a crossing at absolute UTM coordinates (no local origin): ~385 km east, ~6672 km north
    e0, n0 = 385945.123, 6672301.456
    from tests.entitynet.client_fixtures import make_topology

    nodes = {"C": (e0, n0), "W": (e0 - 100.0, n0), "E": (e0 + 100.0, n0), "N": (e0, n0 + 100.0)}
    topo = make_topology(nodes, [("W", "C"), ("C", "E"), ("C", "N")])
    p = Player(topo, 1, "car")
    (m,) = p.feed(e0 - 50.0, n0 + 0.3, 0.0)
    g = decode(m.payload, netview(topo))
    x, y = g.xy_at(0.0)
    assert abs(y - n0) < 0.01 and abs(x - (e0 - 50.0)) < 0.5
    assert decode(encode(g), netview(topo)).xy_at(3.0) == g.xy_at(3.0)


def test_entity_longer_than_a_chain_of_short_edges_occupies_all_of_them():
    topo = chain(n=12, piece=3.0, lead=50.0)
    p = Player(topo, 1, "tram", threshold=5.0)
    for i in range(12):
        out = p.feed(10.0 * i, 0.0, float(i))
    (m,) = p.tick(p.pub_t + p.occupation.validity) or [None]
    assert m is not None or out
    path = p.ghost.path
    s = p.ghost.s_at(p.pub_t)
    assert set(path.cells_between(s - 27.6, s)) <= set(p.occupation.cells)


def test_hours_of_simulated_time_do_not_drift():
    # a pedestrian walking back and forth along a 400 m street for 3 hours at 1 Hz: the receiver error at
    # the end is no worse than in the first minutes (turnarounds at the dead ends cost a few metres of lag)
    topo = cross(arm=200.0)
    p = Player(topo, 1, "pedestrian", threshold=5.0)
    x, v, first, last = -190.0, 1.4, [], []
    n = 3 * 3600
    for i in range(n):
        t = float(i)
        x += v
        if abs(x) > 190.0:
            v = -v
            x += 2 * v
        p.feed(x, 0.0, t)
        gx, _gy = p.ghost.xy_at(t)
        if 60 <= i < 900:
            first.append(abs(gx - x))
        elif i >= n - 840:
            last.append(abs(gx - x))
    assert max(last) <= max(first) + 0.5
    assert max(last) < 10.0
    assert sum(last) / len(last) <= sum(first) / len(first) + 0.5
    assert p.path.length < 2000.0  # the path is trimmed, not growing


def test_network_model_with_huge_time_values_is_stable():
    net = netview(cross())
    m = NetworkModel(1e9, Path(net, [(0, 1), (1, 1)]), 10.0, 1.0, 0.0, 14.0, 0, ())
    back = decode(encode(m), net)
    assert back.xy_at(1e9 + 5.0) == pytest.approx((-85.0, 0.0))
