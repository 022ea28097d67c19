"""The gap limit follows the fix interval the client has observed (issue 21, item 13): a real bus feed sends a
fix every 31-33 s, and with the bus's 30 s `max_gap` every interval published a "gap" (the guess halted) and
then a "start" at the next fix (1.33 publishes per fix). A longer gap than the feed's usual interval is still
a gap, and fixes at 1 Hz change nothing."""

from __future__ import annotations

import numpy as np

from entitynet.client import Player
from entitynet.client.fleet import FleetCore
from entitynet.protocol import Publish, Unpublish
from tests.entitynet.client_fixtures import cross

ARM = 3000.0
TOPO = cross(arm=ARM)
SPEED = 6.0  # m/s along W -> E


def _x(t: float) -> float:
    return -ARM + 50.0 + SPEED * t


def _fix_times(n: int, start: float = 0.0) -> list[float]:
    """n fix times 31, 33, 32, 31, ... s apart (a real bus feed's cadence)."""
    out, t = [], start
    for k in range(n):
        out.append(t)
        t += (31.0, 33.0, 32.0)[k % 3]
    return out


def _drive(p: Player, fixes: list[float], until: float) -> list[tuple[float, Publish | Unpublish]]:
    """Fixes at `fixes` (on the street, no noise), ticks every second between them, up to `until`."""
    return _drive_on(p, fixes, 0.0, until)


def _drive_on(p: Player, fixes: list[float], start: float, until: float) -> list[tuple[float, Publish | Unpublish]]:
    """`_drive` from `start` on (the fixes before it were fed already)."""
    out, k, t = [], sum(1 for f in fixes if f < start), start
    while t <= until:
        if k < len(fixes) and fixes[k] <= t:
            out += [(t, m) for m in p.feed(_x(fixes[k]), 0.0, fixes[k], 4.0)]
            k += 1
        out += [(t, m) for m in p.tick(t)]
        t += 1.0
    return out


def test_a_bus_with_fixes_every_32_s_does_not_gap_at_every_interval():
    p = Player(TOPO, 1, "bus", accuracy=4.0)
    fixes = _fix_times(30)
    # the first three intervals: too few observed to know the cadence, so the 30 s limit gaps
    early = _drive(p, fixes[:4], fixes[3])
    assert p.stats.get("gap", 0) <= 3
    before = dict(p.stats)
    msgs = _drive_on(p, fixes, fixes[3] + 1.0, fixes[-1])
    new = {r: n - before.get(r, 0) for r, n in p.stats.items() if n > before.get(r, 0)}
    assert "gap" not in new and "jump" not in new, new  # main: a gap and a jump (or start) at every fix
    # once the filter has the speed, mostly the keep-alive: the occupation's validity (at most 60 s) runs out
    # about every second fix, 0.53 a fix (main: 2 a fix, a gap and a jump)
    settled = [t for t, _m in msgs if t > fixes[8]]
    assert len(settled) <= 0.7 * (len(fixes) - 9), (len(settled), new)
    assert not any(isinstance(m, Unpublish) for _t, m in early + msgs)
    assert p.rules.max_gap == 30.0  # the configured limit, shorter than the feed's interval
    assert p.rules.gap_limit > 33.0  # ... and the one the client has learnt


def test_a_real_gap_in_a_32_s_feed_is_still_a_gap():
    p = Player(TOPO, 1, "bus", accuracy=4.0)
    fixes = _fix_times(10)
    _drive(p, fixes, fixes[-1])
    gaps_before = p.stats.get("gap", 0)
    last = fixes[-1]
    halted_at = None
    t = last
    while t < last + 300.0:  # five minutes without a fix
        t += 1.0
        for m in p.tick(t):
            if isinstance(m, Publish) and halted_at is None and p.stats.get("gap", 0) > gaps_before:
                halted_at = t
    assert halted_at is not None and halted_at - last <= 0.5 * p.etype.lost_after  # a bounded limit
    assert not p.published  # and lost after `lost_after`
    assert p.stats.get("lost") == 1


def test_fixes_at_1_hz_keep_the_configured_limit():
    p = Player(TOPO, 1, "bus", accuracy=4.0)
    _drive(p, [float(k) for k in range(60)], 59.0)
    assert p.rules.gap_limit == p.rules.max_gap == 30.0


def test_one_long_interval_does_not_stretch_the_limit():
    p = Player(TOPO, 1, "car", accuracy=4.0)
    fixes = [float(k) for k in range(10)] + [10.0 + 90.0] + [101.0 + k for k in range(5)]
    _drive(p, fixes, fixes[-1])
    assert p.rules.gap_limit == p.rules.max_gap  # a median: one 90 s hole is not the feed's cadence


def _twin_run(fixes: list[float], x_of, until: float, etype: str = "bus"):
    """The same fixes through a per-entity Player and through FleetCore: (messages of each, core, its Player)."""
    a, b = Player(TOPO, 1, etype, accuracy=4.0), Player(TOPO, 1, etype, accuracy=4.0)
    core = FleetCore()
    slot = core.add(b)
    got_a, got_b, k, t = [], [], 0, 0.0
    while t <= until:
        if k < len(fixes) and fixes[k] <= t:
            x = x_of(fixes[k])
            got_a += [(t, m) for m in a.feed(x, 0.0, t, 4.0) + a.tick(t)]
            res, _ = core.step(t, [slot], np.array([x]), np.array([0.0]), 4.0)
            k += 1
        else:
            got_a += [(t, m) for m in a.tick(t)]
            res, _ = core.step(t, [], np.zeros(0), np.zeros(0), 4.0)
        got_b += [(t, m) for _s, ms in res for m in ms]
        t += 1.0
    return got_a, got_b, core, a, core.player(slot)


def test_the_fleet_core_learns_the_interval_as_the_player_does():
    """The fleet core's vectorised fixes keep the intervals too: the same messages as a per-entity Player."""
    fixes = _fix_times(30)
    got_a, got_b, core, a, b = _twin_run(fixes, _x, fixes[-1] + 200.0)
    assert got_a == got_b
    assert core.counters["vector_fixes"] > 10  # the vectorised path carried most fixes
    assert b.rules.gap_limit == a.rules.gap_limit and b.tracker.reach == a.tracker.reach


def test_the_fleet_core_follows_a_cadence_that_slows_down():
    """1 Hz, then a fix every 20 s at walking pace (each one taken by the vectorised path), then a 45 s pause:
    the learnt limit (50 s) is no gap, the configured one (30 s) would have been."""
    fixes = [float(k) for k in range(20)] + [19.0 + 20.0 * k for k in range(1, 10)]
    fixes += [fixes[-1] + 45.0 + k for k in range(10)]
    got_a, got_b, core, a, b = _twin_run(fixes, lambda t: -ARM + 50.0 + 1.0 * t, fixes[-1] + 5.0)
    assert a.rules.gap_limit == b.rules.gap_limit
    assert core.counters["vector_fixes"] > 20
    assert got_a == got_b


def test_reach_and_the_gap_limit_always_follow_the_usual_interval():
    """`note_interval` writes the usual interval, the gap limit and the tracker's `reach` only when the interval
    changes: that is exact only while nothing else moves them. After every fix of an irregular feed (jittered,
    stepping cadences, long losses that are not kept, ticks into a loss and back) they are what the interval
    says: `gap_limit(...)` and `follow_cadence`'s max(reacquire, vmax x interval)."""
    from entitynet.client.rules import gap_limit

    rng = np.random.default_rng(22)
    for etype in ("bus", "car", "pedestrian"):
        p = Player(TOPO, 1, etype, accuracy=5.0)
        trk, rules = p.tracker, p.rules
        t, x = 0.0, -ARM + 50.0
        for k in range(300):
            dt = float((rng.uniform(0.5, 1.5), rng.choice([1.0, 2.0, 5.0, 31.0]), rng.uniform(0.1, 200.0))[k // 100])
            t += dt
            x = min(x + SPEED * dt, ARM - 50.0)
            p.tick(t - 0.5 * dt)
            p.feed(x + float(rng.normal(0.0, 3.0)), float(rng.normal(0.0, 3.0)), t)
            assert rules.gap_limit == gap_limit(rules.max_gap, rules.lost_after, rules.interval), (etype, k)
            assert trk.reach == max(trk.placer.reacquire, trk.etype.vmax * rules.interval), (etype, k)
