"""Doppler velocity in a fix: the receiver's speed and heading folded into the along-path and world filters."""

import math
import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from entitynet.client import FixRejected, Player
from entitynet.client.filters import Kinematic1D
from tests.entitynet.client_fixtures import cross


def _run(aided: bool, n: int = 120, seed: int = 3) -> Player:
    """A car at 10 m/s eastwards through the crossing, 5 m GPS (3.54 m per axis), Doppler 0.3 m/s per axis."""
    rng = random.Random(seed)
    p = Player(cross(arm=800.0), 1, "car", threshold=5.0)
    for i in range(n):
        x = -790.0 + 10.0 * i
        fx, fy = x + rng.gauss(0.0, 3.54), rng.gauss(0.0, 3.54)
        vx, vy = 10.0 + rng.gauss(0.0, 0.3), rng.gauss(0.0, 0.3)
        if aided:
            p.feed(fx, fy, float(i), speed=math.hypot(vx, vy), heading=math.degrees(math.atan2(vx, vy)),
                   speed_accuracy=0.3)
        else:
            p.feed(fx, fy, float(i))
    return p


def test_doppler_makes_the_speed_estimate_and_the_ghost_last_longer():
    aided, plain = _run(True), _run(False)
    assert abs(aided.kf.v - 10.0) < 0.5
    drifts_aided, drifts_plain = aided.stats.get("drift", 0), plain.stats.get("drift", 0)
    assert drifts_aided < drifts_plain, (aided.stats, plain.stats)


def _standing_with(heading: float, route=None) -> Player:
    p = Player(cross(arm=400.0), 1, "car", threshold=5.0, route=route)
    for i in range(8):
        p.feed(-300.0, 0.0, float(i), speed=5.0, heading=heading, speed_accuracy=0.2)
    return p


def _path_direction_x(p: Player) -> float:
    s = p.kf.s
    return p.path.xy(s + 1.0)[0] - p.path.xy(s)[0]


def test_the_velocity_counts_by_its_component_along_the_path():
    east, west, north = _standing_with(90.0), _standing_with(270.0), _standing_with(0.0)
    # the street runs east-west: an eastward velocity is forward on an eastward path, backward on a westward one
    assert east.kf.v * _path_direction_x(east) > 0.0
    assert west.kf.v * _path_direction_x(west) < 0.0
    assert abs(north.kf.v) < 0.5  # across the street: no speed along it


def test_a_route_follower_ignores_a_velocity_against_its_route():
    """Where a route passes the same place twice (a terminus loop), the estimate may sit on the other leg:
    a velocity against the route then says nothing about the speed along it."""
    free = _standing_with(270.0)
    on_route = _standing_with(270.0, route=[(0, 1), (1, 1)])  # W -> C -> E: eastwards
    assert free.kf.v * _path_direction_x(free) < -2.0
    assert abs(on_route.kf.v) < 0.5


def test_a_standing_receiver_may_omit_the_heading():
    p = Player(cross(), 1, "car")
    p.feed(-50.0, 0.0, 0.0, speed=0.0)
    p.feed(-50.0, 0.0, 1.0, speed=0.0)
    assert p.last_t == 1.0 and abs(p.kf.v) < 0.5


def test_world_models_take_both_components():
    p = Player(None, 1, "car", model="fpw")
    for i in range(5):
        p.feed(0.0, 0.0, float(i), speed=8.0, heading=45.0, speed_accuracy=0.1)
    assert p.world.kx.v == pytest.approx(8.0 / math.sqrt(2.0), abs=0.3)
    assert p.world.ky.v == pytest.approx(8.0 / math.sqrt(2.0), abs=0.3)


@pytest.mark.parametrize("kw", [dict(speed=math.nan, heading=0.0), dict(speed=-1.0, heading=0.0),
                                dict(speed=math.inf, heading=0.0), dict(speed=3.0), dict(speed=math.nan),
                                dict(speed=3.0, heading=math.nan), dict(speed=3.0, heading=0.0, speed_accuracy=0.0),
                                dict(speed=3.0, heading=0.0, speed_accuracy=math.inf)])
def test_bad_doppler_is_rejected_and_changes_nothing(kw):
    p = Player(cross(), 1, "car")
    p.feed(-50.0, 0.0, 10.0, speed=2.0, heading=90.0)
    before = (p.seq, p.last_t, p.measured, p.kf.s, p.kf.v, dict(p.stats))
    with pytest.raises(FixRejected):
        p.feed(-48.0, 0.0, 11.0, **kw)
    assert (p.seq, p.last_t, p.measured, p.kf.s, p.kf.v, dict(p.stats)) == before
    p.feed(-48.0, 0.0, 11.0, speed=2.0, heading=90.0)  # and the next good fix is taken
    assert p.last_t == 11.0


@given(st.floats(-30.0, 30.0), st.floats(0.0, 40.0), st.floats(1e-4, 25.0), st.booleans(),
       st.integers(1, 6))
def test_a_speed_measurement_moves_the_speed_towards_it_and_never_adds_uncertainty(v0, z, r, accel, steps):
    f = Kinematic1D(0.0, 0.0, 25.0, q=0.3, accel=accel)
    for k in range(1, steps + 1):
        f.update(v0 * k, float(k), 25.0)
    v, p00, p11, p22 = f.v, f.p00, f.p11, f.p22
    f.update_speed(z, r)
    assert min(v, z) - 1e-9 <= f.v <= max(v, z) + 1e-9
    assert f.p11 <= p11 + 1e-12 and f.p00 <= p00 + 1e-12 and f.p22 <= p22 + 1e-12
    assert f.p00 >= 0.0 and f.p11 >= 0.0 and f.p22 >= -1e-12
    assert all(math.isfinite(x) for x in (f.s, f.v, f.a, f.p00, f.p01, f.p02, f.p11, f.p12, f.p22))
