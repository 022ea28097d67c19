"""Extrapolation limits (issue 9, item 13): a guess carried across a fix gap stays bounded in time and distance,
stops after `max_gap`, and the entity is unpublished after `lost_after`; receivers' ghosts are capped too."""

import math

import pytest

from entitynet.client import FixRejected, GhostStore, Player, decode, encode, netview
from entitynet.client.entities import TYPES
from entitynet.client.limits import HORIZON, MAX_SPEED, max_speed, world_state
from entitynet.client.motion import AreaModel, NetworkModel, WorldModel
from entitynet.client.path import Path
from entitynet.protocol import Publish, Unpublish, Update
from tests.entitynet.client_fixtures import cross, make_topology
from topology.raw import TRAM

ARM = 3000.0
_TOPOS: dict[str, object] = {}


def topo_for(etype: str):
    """A long X crossing on the type's network (trams need rails), built once per network."""
    key = "tram" if etype == "tram" else "street"
    if key not in _TOPOS:
        if key == "tram":
            nodes = {"C": (0.0, 0.0), "W": (-ARM, 0.0), "E": (ARM, 0.0), "S": (0.0, -ARM), "N": (0.0, ARM)}
            edges = [("W", "C", TRAM), ("C", "E", TRAM), ("S", "C", TRAM), ("C", "N", TRAM)]
            _TOPOS[key] = make_topology(nodes, edges, junction_radius=20.0)
        else:
            _TOPOS[key] = cross(arm=ARM)
    return _TOPOS[key]


def accelerate(p: Player, n: int = 12) -> tuple[float, float, float]:
    """Fixes at 1 Hz of an entity accelerating east from 20 % to 80 % of its type's vmax (what makes an FVW guess
    run away). Returns the last fix (x, y, t)."""
    et = p.etype
    v0, a = 0.2 * et.vmax, 0.6 * et.vmax / n
    x = y = 0.0
    for i in range(n + 1):
        x, y = -ARM + 100.0 + v0 * i + 0.5 * a * i * i, 0.0
        p.feed(x, y, float(i))
    return x, y, float(n)


def run_gap(p: Player, last: float, gap: float, step: float) -> list[tuple[float, Publish | Unpublish]]:
    out = []
    t = last
    while t < last + gap:
        t = min(t + step, last + gap)
        out += [(t, m) for m in p.tick(t)]
    return out


CASES = [(model, etype) for model in ("network", "fpw", "fvw", "periodic")
         for etype in ("pedestrian", "car", "bus", "tram")]


@pytest.mark.parametrize("gap,step", [(208.0, 1.0), (3 * 3600.0, 7.0)], ids=["208s", "3h"])
@pytest.mark.parametrize("model,etype", CASES)
def test_a_fix_gap_stops_the_guess_then_unpublishes(model, etype, gap, step):
    p = Player(topo_for(etype), 1, etype, model=model)
    et = p.etype
    net = p.net
    fx, fy, last = accelerate(p)
    ghost_at_fix = p.ghost.xy_at(last)
    msgs = run_gap(p, last, gap, step)
    # the guess never goes further than the type's speed cap allows for max_gap seconds
    bound = et.max_speed * et.max_gap + 2.0 * p.threshold
    ghost = p.ghost
    t = last
    published = []
    for tm, m in msgs:
        while ghost is not None and t < tm:  # sample the ghost in force before this message, every second
            x, y = ghost.xy_at(t)
            assert math.hypot(x - ghost_at_fix[0], y - ghost_at_fix[1]) <= bound, (t, model, etype)
            t += 1.0
        if isinstance(m, Publish):
            ghost = decode(m.payload, net)
            published.append((tm, m, ghost))
        else:
            ghost = None
    # a standing model was published once, when the fixes had stopped for max_gap seconds
    assert p.stats.get("gap") == 1
    stops = [(tm, g) for tm, m, g in published if tm >= last + et.max_gap]
    assert stops, "no standing model after the gap"
    t_stop, g_stop = stops[0]
    assert t_stop - last == pytest.approx(et.max_gap, abs=step)
    x0, y0, v0 = g_stop.xy_speed_at(t_stop)
    assert v0 == 0.0 and g_stop.xy_at(t_stop + 50.0) == pytest.approx((x0, y0))
    assert math.hypot(x0 - ghost_at_fix[0], y0 - ghost_at_fix[1]) <= bound
    # then one UNPUBLISH after lost_after, and nothing more
    kinds = [type(m) for _, m in msgs]
    assert kinds.count(Unpublish) == 1
    k = kinds.index(Unpublish)
    t_lost = msgs[k][0]
    assert et.lost_after <= t_lost - last < et.lost_after + step
    assert k == len(msgs) - 1 and p.stats.get("lost") == 1 and not p.published
    # a fix after the gap publishes afresh
    (m,) = p.feed(fx + 10.0, fy, last + gap + 1.0)
    assert isinstance(m, Publish) and p.published


def test_no_gap_no_limit_reason():
    p = Player(topo_for("car"), 1, "car", model="fvw")
    accelerate(p, n=40)
    assert "gap" not in p.stats and "lost" not in p.stats


def test_per_type_limits_and_overrides():
    for et in TYPES.values():
        assert et.vmax <= et.max_speed <= MAX_SPEED
        assert 0.0 < et.max_gap <= et.lost_after
    p = Player(topo_for("car"), 1, "car", max_gap=5.0, lost_after=9.0)
    _, _, last = accelerate(p)
    assert p.tick(last + 5.0) and p.stats["gap"] == 1
    assert p.tick(last + 9.0) == [Unpublish(1)]
    with pytest.raises(ValueError):
        Player(topo_for("car"), 1, "car", max_gap=10.0, lost_after=5.0)
    with pytest.raises(ValueError):
        Player(topo_for("car"), 1, "car", heartbeat=HORIZON + 1.0)


def test_nan_and_backwards_time_still_rejected_across_a_gap():
    p = Player(topo_for("car"), 1, "car", model="fvw")
    fx, fy, last = accelerate(p)
    p.tick(last + 30.0)  # stopped by the gap
    with pytest.raises(ValueError):
        p.tick(math.nan)
    with pytest.raises(ValueError):
        p.tick(last - 1.0)
    with pytest.raises(FixRejected):
        p.feed(math.nan, fy, last + 31.0)
    with pytest.raises(FixRejected):
        p.feed(fx, fy, last)  # not after the last fix
    assert p.published


# ---- receivers -----------------------------------------------------------------------------------------
def test_world_models_never_run_past_the_horizon_nor_the_speed_cap():
    # an FVW guess of a car at 20 m/s accelerating at 3 m/s^2: uncapped, 174 m/s after a minute
    g = WorldModel(0.0, 0.0, 0.0, 20.0, 0.0, 3.0, 0.0, 1)
    cap = max_speed(1)
    prev = g.xy_at(0.0)
    for t in range(1, 400):
        x, y, v = g.xy_speed_at(float(t))
        assert v <= cap + 1e-9
        assert math.hypot(x - prev[0], y - prev[1]) <= cap + 1e-9  # at most the cap per second
        prev = (x, y)
    assert g.xy_at(10 * 3600.0) == g.xy_at(HORIZON) and g.xy_speed_at(HORIZON + 1.0)[2] == 0.0
    assert math.hypot(*g.xy_at(1e9)) <= cap * HORIZON
    # under the cap the motion is the plain second-order one
    assert g.xy_at(5.0) == pytest.approx((20.0 * 5 + 1.5 * 25, 0.0))
    # a start already faster than the cap is slowed to it; an unknown type code gets the largest cap
    assert WorldModel(0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0).xy_speed_at(1.0)[2] == max_speed(0)
    assert WorldModel(0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 99).xy_at(1.0) == (0.0, MAX_SPEED)
    a = AreaModel(0.0, 0, 0.0, 0.0, 30.0, 40.0, 0)  # 50 m/s on a square
    assert math.hypot(*a.xy_at(1.0)) == pytest.approx(max_speed(0))
    assert a.xy_at(1e6) == a.xy_at(HORIZON)


def test_world_state_reaches_the_cap_continuously():
    for vx, vy, ax, ay in ((1.0, 0.0, 2.0, 0.0), (0.0, 3.0, 1.0, -1.0), (-5.0, 0.0, 4.0, 0.0)):
        cap = 10.0
        dx0 = dy0 = 0.0
        for k in range(1, 200):
            dt = 0.1 * k
            dx, dy, wx, wy = world_state(vx, vy, ax, ay, cap, dt)
            assert math.hypot(wx, wy) <= cap + 1e-9
            assert math.hypot(dx - dx0, dy - dy0) <= cap * 0.1 + 1e-9
            dx0, dy0 = dx, dy


def test_network_models_stand_at_the_horizon_and_receivers_clamp_the_speed():
    net = netview(topo_for("car"))
    path = Path(net, [(0, 1), (1, 1)])
    m = NetworkModel(0.0, path, 0.0, 5.0, 1.0, 25.0, 1, (4.5,))
    assert m.s_at(1e6) == m.s_at(HORIZON) and m.speed_at(HORIZON + 1.0) == 0.0
    assert m.xy_speed_at(1e6) == (*m.xy_at(HORIZON), 0.0)
    assert math.isinf(m.time_to(m.s_at(HORIZON) - m.s0 + 1.0))  # never, consistently with s_at
    # a payload claiming 100 m/s for a pedestrian is believed only up to the pedestrian's cap
    fast = decode(encode(NetworkModel(0.0, path, 0.0, 100.0, 0.0, 100.0, 0, ())), net)
    assert fast.v == fast.vmax == max_speed(0)
    assert fast.s_at(10.0) == pytest.approx(10.0 * max_speed(0))


def test_ghosts_live_at_most_the_horizon_whatever_validity_they_claim():
    gs = GhostStore(None)
    gs.set_visible({1})
    fvw = encode(WorldModel(0.0, 0.0, 0.0, 20.0, 0.0, 3.0, 0.0, 1))
    gs.receive(Update(5, 1, (1,), 10 * 3600 * 1000, fvw), now=0.0)
    (x, y), = gs.positions(HORIZON - 1.0).values()
    assert math.hypot(x, y) <= max_speed(1) * HORIZON
    assert gs.positions(HORIZON) == {} and len(gs) == 0
