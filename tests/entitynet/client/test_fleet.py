"""The fleet core against per-entity Players: the same fixes in, the same messages out, message for message.

Twins: every entity gets two identical Players; one is driven the per-entity way (`feed` + `tick` on a fix,
`tick` otherwise, as `sims.engine.clients.Fleet` does), the other through `FleetCore`. Walkers, cars, buses
and trams (some on a-priori routes with a stop) walk random paths with speed changes, turn-backs and pauses
under 4 m GPS noise on the client fixtures' networks; one entity has a fix gap long enough to halt its ghost,
one is lost, one is removed, one sends a NaN fix, one stands still until its heartbeat. Equality is exact
(frozen dataclasses compare every field, payload bytes included), and the counters prove the vectorised path
carried a good share of the fixes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from entitynet.client import Player, fleet_fix, netview
from entitynet.client.fixes import FixRejected
from entitynet.client.fleet import PRIME_MIN, FleetCore, _deadline
from entitynet.client.path import Path
from tests.entitynet.client.test_player_replay import _walk_path
from tests.entitynet.client_fixtures import area_square, chain, cross, make_topology, parallel
from topology.raw import PEDESTRIAN, VEHICLE

TYPES = ("pedestrian", "car", "bus", "tram", "pedestrian", "car")
STANDS = 5  # this entity stands still throughout: its heartbeat (20 s) runs out between fixes


def _twins(topo, n: int, seed: int):
    """n entities: (player for the per-entity drive, player for the fleet core, truth path, speed)."""
    net = netview(topo)
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        etype = TYPES[i % len(TYPES)]
        networks = PEDESTRIAN if etype == "pedestrian" or topo is AREA else VEHICLE
        if etype == "tram" and topo is AREA:
            etype = "pedestrian"
        path = _walk_path(net, rng, networks)
        if path.length < 30.0:
            path = Path(net, path.edges + [de for de in net.choices(path.edges[-1], networks)[:1]])
        with_route = etype in ("bus", "tram") or i % 5 == 0
        route = path.edges if with_route else None
        stops = [(path.edges[-1][0], 0.5 * float(net.edge_len[path.edges[-1][0]]))] if with_route else ()
        kw = dict(route=route, stops=stops, accuracy=4.0, max_gap=6.0, lost_after=25.0,
                  heartbeat=20.0 if i == STANDS else 60.0)
        out.append([Player(topo, i, etype, **kw), Player(topo, i, etype, **kw), path,
                    float(rng.uniform(0.5, 8.0))])
    return out


def _doppler(rng, path: Path, s: float, v: float) -> tuple[float, float]:
    """A receiver's (speed, heading) for truth speed v at s: along the way with noise, now and then a random
    course (across the way, or against it), a standing one without a course (NaN: `feed`'s None)."""
    u = rng.random()
    if v == 0.0 and u < 0.5:
        return 0.0, math.nan
    (x0, y0), (x1, y1) = path.xy(max(s - 1.0, 0.0)), path.xy(min(s + 1.0, path.length))
    heading = math.degrees(math.atan2(x1 - x0, y1 - y0)) + (180.0 if v < 0.0 else 0.0)
    if u < 0.15:
        heading = float(rng.uniform(0.0, 360.0))
    return max(abs(v) + float(rng.normal(0.0, 0.3)), 0.0), (heading + float(rng.normal(0.0, 4.0))) % 360.0


def _run(topo, n: int = 12, seed: int = 1, ticks: int = 240, doppler: bool = False, prime_min: int = PRIME_MIN):
    """Drive both sides; returns (per-tick messages per entity for each side, the core, the players).
    `doppler`: the fixes come with the receiver's velocity (`_doppler`; one with a speed but no course, refused).
    `prime_min`: the fleet's batch placements from so many fixes (1: every scalar fix that asks is primed)."""
    ents = _twins(topo, n, seed)
    rng = np.random.default_rng(seed + 100)
    core = FleetCore(capacity=4, prime_min=prime_min)  # grows while adding
    slots = [core.add(e[1]) for e in ents]
    s = [0.0] * n
    gaps = {1: (60.0, 69.0), 2: (80.0, 110.0)}  # no fixes: entity 1's ghost halts (gap), entity 2 is lost
    removed_at = {3: 50.0}
    alive = set(range(n))
    got_a, got_b = [], []
    for k in range(ticks):
        t = 0.5 * (k + 1)
        due_b, xs, ys, sp, hd = [], [], [], [], []
        a_out, b_out = {}, {}
        for i in sorted(alive):
            if removed_at.get(i) == t:
                alive.discard(i)
                a_out[i] = ents[i][0].leave()
                b_out[i] = core.remove(slots[i])
                continue
            u = rng.random()
            if i == STANDS:
                ents[i][3] = 0.0
            elif u < 0.03:
                ents[i][3] = -ents[i][3] if rng.random() < 0.4 else float(rng.uniform(0.0, 9.0))
            elif u < 0.05:
                ents[i][3] = 0.0
            s[i] = min(max(s[i] + 0.5 * ents[i][3], 0.0), ents[i][2].length)
            g0, g1 = gaps.get(i, (0.0, 0.0))
            fix = (k % 2 == 1) and not (g0 <= t < g1)
            p = ents[i][0]
            if fix:
                x, y = ents[i][2].xy(s[i])
                x, y = x + float(rng.normal(0.0, 3.0)), y + float(rng.normal(0.0, 3.0))
                if i == 4 and k == 101:
                    x = math.nan  # a bad fix: refused by both, nothing else lost
                speed, heading = _doppler(rng, ents[i][2], s[i], ents[i][3]) if doppler else (math.nan, math.nan)
                if doppler and i == 6 and k == 61:
                    speed, heading = 3.0, math.nan  # a speed without its course: refused by both
                try:
                    a_out[i] = p.feed(x, y, t, 4.0, speed=None if speed != speed else speed,
                                      heading=None if heading != heading else heading, speed_accuracy=0.3)
                    a_out[i] += p.tick(t)
                except FixRejected:
                    a_out[i] = []
                due_b.append(slots[i])
                xs.append(x)
                ys.append(y)
                sp.append(speed)
                hd.append(heading)
            else:
                a_out[i] = p.tick(t)
        vel = dict(speed=np.array(sp), heading=np.array(hd), speed_accuracy=0.3) if doppler else {}
        res, _rej = core.step(t, due_b, np.array(xs), np.array(ys), 4.0, **vel)
        b_out.update({ents[sl][1].entity: m for sl, m in res})
        got_a.append({i: m for i, m in a_out.items() if m})
        got_b.append({i: m for i, m in b_out.items() if m})
    return got_a, got_b, core, ents


AREA = area_square()


@pytest.mark.parametrize(("topo", "share"), [(cross(arm=100.0), 0.25), (parallel(gap=12.0, length=300.0), 0.25),
                                             (chain(), 0.1), (AREA, 0.25)],
                         ids=["cross", "parallel", "chain", "area"])
@pytest.mark.parametrize(("seed", "doppler"), [(1, False), (2, False), (3, True), (4, True)])
def test_fleet_core_publishes_what_each_player_publishes(topo, share, seed, doppler):
    """`share`: the least fraction of fixes the arrays must carry (in the area map every way ends at the
    area: only fixes beyond the switch margin, outside the area, are decided in arrays). `doppler`: the fixes
    carry the receiver's velocity (as a proxy's vehicles do), folded in by the arrays too. Odd seeds prime the
    placement index for every scalar fix that asks it (`prime_min=1`): the primed answers give the same
    messages."""
    prime_min = 1 if seed % 2 else PRIME_MIN
    index = topo.placement_index()
    hits = index.primed_hits
    got_a, got_b, core, ents = _run(topo, seed=seed, doppler=doppler, prime_min=prime_min)
    for k, (a, b) in enumerate(zip(got_a, got_b, strict=True)):
        assert a == b, f"tick {k}: per-entity {a} != fleet {b}"
    c = core.counters
    assert c["vector_fixes"] >= share * (c["vector_fixes"] + c["scalar_fixes"]), c  # the arrays did the work
    assert c["scalar_ticks"] > 0
    assert c["vector_near"] > 0  # fixes beyond the switch margin too (`Placer.near` in arrays)
    # `_best_on` and the hysteresis between ways (or before an area's entry), in arrays too
    assert c["vector_best_on"] > 0 and c["vector_hysteresis"] > 0, c
    assert c["vector_publishes"] > 0  # (decided in arrays, built by the Player)
    assert (c["vector_velocity"] > 0) == doppler, c  # (the velocity folded in by the arrays)
    if prime_min == 1:  # (the first fixes at least were primed, and their placements read from the batch)
        assert c["primed_places"] >= len(ents) and index.primed_hits - hits >= len(ents), c
    stats: dict[str, int] = {}
    for e in ents:  # (stats change only in scalar calls: the fleet's players hold them)
        for key, v in e[1].stats.items():
            stats[key] = stats.get(key, 0) + v
    assert stats == {key: sum(e[0].stats.get(key, 0) for e in ents) for key in stats}
    assert stats.get("gap") and stats.get("lost") and (stats.get("expiry") or stats.get("heartbeat")), stats
    assert sum(len(m) for tick in got_a for m in tick.values()) > 100


def _state(p: Player) -> tuple:
    """The state a fix changes: fix history, tracker, along-path filter, update rules."""
    trk, kf = p.tracker, p.tracker.kf
    return (p.last_t, p.measured, trk.recent_s, p.rules.recent, p.rules.over, trk.last_fix, trk.dist_ema, trk.vpeak,
            trk.pending,
            None if kf is None else [getattr(kf, f) for f in kf.FIELDS])


def test_written_back_state_is_the_players_own():
    """After vectorised fixes, `player(slot)` writes the arrays back: the twin driven per entity holds the same
    tracker, filter and rule state, field for field."""
    _a, _b, core, ents = _run(parallel(gap=12.0, length=300.0), n=6, ticks=120)
    live = [slot for slot in range(len(ents)) if core.players[slot] is not None]
    assert len(live) >= 4
    for slot in live:
        assert _state(ents[slot][0]) == _state(core.player(slot))


@pytest.mark.parametrize(("error", "seen_in"), [(1e-9, "state"), (0.5, "messages")])
def test_the_comparisons_see_an_error(monkeypatch, error, seen_in):
    """Both checks above can fail: a filter update off by 1e-9 m in the arrays shows in the written-back state
    (the payload's quantisation hides it from the messages for a while), one off by 0.5 m in the messages."""
    real = fleet_fix.kf_update
    monkeypatch.setattr(fleet_fix, "kf_update", lambda z, *a: real(z + error, *a))
    got_a, got_b, core, ents = _run(parallel(gap=12.0, length=300.0), n=6, ticks=120)
    if seen_in == "messages":
        assert got_a != got_b
    else:
        live = [slot for slot in range(len(ents)) if core.players[slot] is not None]
        assert any(_state(ents[slot][0]) != _state(core.player(slot)) for slot in live)


def test_before_its_deadline_tick_says_nothing_and_at_the_limit_it_speaks():
    """The timer array's exactness: `tick` returns nothing (and changes nothing) at any time before the
    deadline, and the deadline is within 1e-5 s of the first time it returns a message."""
    topo = cross(arm=100.0)
    p = Player(topo, 1, "car", accuracy=4.0, max_gap=6.0, lost_after=25.0)
    assert _deadline(p) == math.inf
    for k in range(5):
        p.feed(10.0 + 5.0 * k, 1.0, float(k + 1))
    d = _deadline(p)
    assert math.isfinite(d) and d > 5.0
    for t in np.linspace(5.0, d, 200)[:-1].tolist() + [d]:
        assert p.tick(t) == []
    lo, hi = d, d + 1.0
    while hi - lo > 1e-7:  # the first time tick answers, by bisection (`on_tick` notes a gap: undone each time)
        mid = 0.5 * (lo + hi)
        halted = p.rules.halted
        answer = p.rules.on_tick(mid, p.last_t, p.pub_t, p.occupation)[0]
        p.rules.halted = halted
        if answer is None:
            lo = mid
        else:
            hi = mid
    assert 0.0 < hi - d < 1e-5
    assert p.tick(hi)


def test_bad_input_is_refused_cleanly():
    core = FleetCore()
    p = Player(cross(arm=100.0), 1, "pedestrian", accuracy=4.0)
    slot = core.add(p)
    out, rejected = core.step(1.0, [slot], np.array([math.inf]), np.array([0.0]), 4.0)
    assert (out, rejected) == ([], 1)
    with pytest.raises(ValueError, match="before the last step"):
        core.step(0.5, [], np.zeros(0), np.zeros(0), 4.0)
    with pytest.raises(ValueError, match="finite"):
        core.step(math.nan, [], np.zeros(0), np.zeros(0), 4.0)
    core.remove(slot)
    with pytest.raises(KeyError):
        core.player(slot)


def test_twins_agree_through_readds_option_changes_repeated_times_and_a_zero_length_edge():
    """What the twin run above does not do: a Player removed and added again (its slot reused), options changed
    through `player(slot)`, steps at the same time as the last (a second fix at that time is refused by both),
    the accuracy changing between steps, fixes exactly on the ways and nodes, on a map with a zero-length edge
    (two nodes at one point) where paths pass edges twice."""
    topo = make_topology({"A": (0.0, 0.0), "B": (50.0, 0.0), "C": (50.0, 0.0), "D": (120.0, 0.0),
                          "E": (50.0, 60.0), "F": (50.0, -40.0)},
                         [("A", "B"), ("B", "C"), ("C", "D"), ("C", "E"), ("C", "F"), ("F", "B")])
    net = netview(topo)
    rng = np.random.default_rng(7)
    ents = []
    for i in range(8):
        etype = TYPES[i % len(TYPES)]
        path = _walk_path(net, rng, PEDESTRIAN if etype == "pedestrian" else VEHICLE)
        route = path.edges if i % 3 == 0 else None
        kw = dict(route=route, accuracy=4.0, max_gap=6.0, lost_after=25.0, heartbeat=20.0 + 10.0 * (i % 3),
                  threshold=(None, 2.0, 10.0)[i % 3], confirm=1 + i % 2)
        ents.append([Player(topo, i, etype, **kw), Player(topo, i, etype, **kw), path, float(rng.uniform(1.0, 9.0))])
    core = FleetCore(capacity=2)
    slots = [core.add(e[1]) for e in ents]
    s = [float(rng.uniform(0.0, e[2].length)) for e in ents]
    t, readds, changes = 0.0, 0, 0
    for k in range(300):
        dt = float(rng.choice([0.0, 0.25, 0.5, 1.0, 1.0, 2.0]))
        t += dt
        acc = float(rng.choice([2.0, 4.0, 9.0]))
        due, xs, ys, a_out, b_out = [], [], [], {}, {}
        for i, e in enumerate(ents):
            u = rng.random()
            if u < 0.01:  # removed and added again: its slot may be another now
                a_out[i] = e[0].leave()
                b_out[i] = core.remove(slots[i])
                slots[i] = core.add(e[1])
                readds += 1
                continue
            if u > 0.995:
                changes += 1
                for p in (e[0], core.player(slots[i])):
                    p.tracker.switch_margin = 5.0 if p.tracker.switch_margin is None else None
                    p.tracker.switch_count = 1 if p.tracker.switch_count is None else None
            if u < 0.05:
                e[3] = -e[3] if rng.random() < 0.5 else float(rng.uniform(0.0, 12.0))
            s[i] = min(max(s[i] + dt * e[3], 0.0), e[2].length)
            if rng.random() < 0.6:
                x, y = e[2].xy(s[i])
                noise = float(rng.choice([0.0, 1.0, 4.0, 8.0]))
                x, y = x + float(rng.normal(0.0, noise)), y + float(rng.normal(0.0, noise))
                if rng.random() < 0.1:
                    x, y = float(round(x)), float(round(y))
                try:
                    a_out[i] = e[0].feed(x, y, t, acc) + e[0].tick(t)
                except FixRejected:
                    a_out[i] = []
                due.append(slots[i])
                xs.append(x)
                ys.append(y)
            else:
                a_out[i] = e[0].tick(t)
        res, _rej = core.step(t, due, np.array(xs), np.array(ys), acc)
        b_out.update({core.players[sl].entity: m for sl, m in res})
        assert {i: m for i, m in a_out.items() if m} == {i: m for i, m in b_out.items() if m}, (k, t)
    assert readds >= 5 and changes >= 5
    for i, e in enumerate(ents):
        assert _state(e[0]) == _state(core.player(slots[i])), i
    c = core.counters
    assert c["vector_fixes"] > c["scalar_fixes"] and c["vector_near"] and c["vector_best_on"], c
