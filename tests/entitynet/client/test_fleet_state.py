"""One home for client state (issue 22): a fleet core's entities keep their state in the fleet's record
(entitynet/client/state.py), which the arrays and the Players' parts both read and write, nothing copied; what
the fleet core keeps besides (the ghost's and the options' columns) is derived and read again when the ghost or
the Player changes. And a fix whose path must be extended ahead does not leave the arrays for it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from entitynet.client.fleet import FleetCore
from entitynet.client.player import Player
from tests.entitynet.client.test_fleet import _run
from tests.entitynet.client_fixtures import chain, cross, parallel


def _fast_slot(core) -> int:
    slots = [s for s in range(len(core.players)) if core.players[s] is not None and core.fast[s]]
    assert slots, "no entity on the vectorised path"
    return slots[0]


def test_the_arrays_and_the_player_are_one_state():
    """A field written through the Player is what the arrays read, and one written in the arrays is what
    the Player reads: the same memory, not a copy."""
    _a, _b, core, _ents = _run(parallel(gap=12.0, length=300.0), n=6, ticks=60)
    s = _fast_slot(core)
    p = core.player(s)
    p.tracker.dist_ema = 12.5
    p.rules.over = 3
    assert core.dist_ema[s] == 12.5 and core.over[s] == 3
    core.ks[s] += 1.0
    core.rs[s, -1] = -4.0
    assert p.kf.s == core.ks[s] and p.tracker.recent_s[-1] == -4.0
    assert p.last_t == core.last_t[s] and p.measured[:2] == (core.mx[s], core.my[s])
    # the path: the row's arrays, the `Path` built from them once per change
    path = p.tracker.path
    assert p.tracker.path is path and [de[0] for de in path.edges] == core.pe[s, : core.pn[s]].tolist()


def test_a_player_added_moves_its_row_and_removed_takes_it_along():
    topo = cross(arm=100.0)
    p = Player(topo, 1, "car", accuracy=4.0)
    for k in range(4):
        p.feed(10.0 + 5.0 * k, 1.0, float(k + 1))
    before = (p.last_t, p.measured, p.kf.s, p.kf.p00, p.tracker.recent_s, p.rules.recent, p.tracker.path)
    own = p._st
    core = FleetCore()
    slot = core.add(p)
    assert p._st is core.rec and p.tracker._st is core.rec and p.rules._st is core.rec
    assert (p.last_t, p.measured, p.kf.s, p.kf.p00, p.tracker.recent_s, p.rules.recent, p.tracker.path) == before
    own.f[0] = -1.0  # the old row is left behind: writing it changes nothing
    assert p.last_t == before[0]
    core.remove(slot)
    assert p._st is not core.rec
    assert (p.last_t, p.measured, p.kf.s, p.kf.p00, p.tracker.recent_s, p.rules.recent, p.tracker.path) == before


def test_the_ghost_and_the_options_are_read_when_they_change():
    _a, _b, core, _ents = _run(parallel(gap=12.0, length=300.0), n=6, ticks=60)
    s = _fast_slot(core)
    core.gm[s] = -7.0  # sentinels: a refresh with the same ghost and options keeps them
    core.cm[s] = -7.0
    core._refresh(s)
    assert (core.gm[s] == -7.0).all() and (core.cm[s] == -7.0).all()
    p = core.player(s)  # handing the Player out reads its options and ghost again
    p.rules.threshold = 123.0  # a change made through the handed-out Player
    core._refresh(s)
    assert core.thr[s] == 123.0 and core.g_t0[s] == p.ghost.t0
    # a publish (here: the fix gap's, `max_gap` after the last fix) makes a new ghost: its columns follow it
    ghost = p.ghost
    msgs = p.tick(min(p.last_t + p.rules.max_gap, p.pub_t + p.rules.validity(p.occupation)))
    assert msgs and p.ghost is not ghost
    core._refresh(s)
    assert core.pub_t[s] == p.pub_t
    assert core.g_t0[s] == p.ghost.t0 and core.g_s0[s] == p.ghost.s0
    assert math.isfinite(core.swm[s])


@pytest.mark.parametrize("topo", [parallel(gap=12.0, length=300.0), chain(), cross(arm=100.0)])
def test_paths_extended_in_arrays_give_the_players_messages_and_state(topo):
    """A fix whose path needs extending ahead (`_maintain_path`) stays in arrays: the edges `follow` gives are
    appended row by row (a dead end is remembered); the messages and the paths are the twins'."""
    got_a, got_b, core, ents = _run(topo, n=12, ticks=160)
    assert got_a == got_b
    assert core.counters["vector_extends"] > 0
    for s, e in enumerate(ents):
        if core.players[s] is None:
            continue
        p, twin = core.player(s), e[0]
        if p.tracker is not None and p.tracker.path is not None and twin.tracker.path is not None:
            assert p.tracker.path == twin.tracker.path and p.tracker.path.cum == twin.tracker.path.cum
            assert p.tracker.dead_end == twin.tracker.dead_end


def test_a_removed_slot_goes_to_the_next_player_and_messages_keep_the_order_of_the_adds():
    topo = cross(arm=100.0)
    core = FleetCore(capacity=2)
    players = [Player(topo, k, "car", accuracy=4.0) for k in range(3)]
    slots = [core.add(p) for p in players]
    assert slots == [0, 1, 2] and core.rec.rows == 3
    core.remove(0)
    late = Player(topo, 9, "car", accuracy=4.0)
    assert core.add(late) == 0 and core.rec.rows == 3  # the removed one's slot and row, not a new one
    assert late._st is core.rec and players[0]._st is not core.rec
    # everyone's first fix publishes: the messages come in the order of the adds (1, 2, then 9 in slot 0)
    out, rejected = core.step(1.0, [0, 1, 2], np.array([10.0, 20.0, 30.0]), np.array([1.0, 1.0, 1.0]), 4.0)
    assert rejected == 0 and [s for s, _m in out] == [1, 2, 0]
    assert [m[0].entity for _s, m in out] == [1, 2, 9]


def test_a_player_in_a_fleet_core_is_not_added_again_until_removed():
    """One Player, one slot: a second `add` (to this fleet core or another) would step it twice, once on a row
    nobody reads; it is refused, nothing changes, and after `remove` the Player may be added again."""
    topo = cross(arm=100.0)
    p = Player(topo, 1, "car", accuracy=4.0)
    core, other = FleetCore(), FleetCore()
    slot = core.add(p)
    for fleet in (core, other):
        with pytest.raises(ValueError, match="in a fleet core already"):
            fleet.add(p)
    assert core.rec.rows == 1 and other.rec.rows == 0 and p._st is core.rec and core.player(slot) is p
    core.remove(slot)
    assert other.add(p) == 0 and p._st is other.rec


def test_a_change_through_a_handed_out_player_counts_from_the_next_step():
    """`player(slot)` hands the Player out for changes (its options, a fix fed directly): the fleet core's
    derived columns (options, ghost, deadline, eligibility) are read again before its next step uses them, so
    the next fixes decide what the Player alone decides (here: a drift threshold lowered mid-run)."""
    from tests.entitynet.client.test_fleet import _twins

    topo = parallel(gap=12.0, length=300.0)
    ents = _twins(topo, 6, 1)
    core = FleetCore()
    slots = [core.add(e[1]) for e in ents]
    rng = np.random.default_rng(7)
    s = [0.0] * len(ents)
    for k in range(80):
        t = float(k + 1)
        if k == 40:
            assert core.fast[slots].any()  # (some entities are on the arrays' path when it changes)
            for sl, e in zip(slots, ents, strict=True):
                core.player(sl).rules.threshold = e[0].rules.threshold = 1.0
        xs, ys, want = [], [], {}
        for i, e in enumerate(ents):
            s[i] = min(s[i] + e[3], e[2].length)
            x, y = e[2].xy(s[i])
            x, y = x + float(rng.normal(0.0, 3.0)), y + float(rng.normal(0.0, 3.0))
            xs.append(x)
            ys.append(y)
            msgs = e[0].feed(x, y, t, 4.0) + e[0].tick(t)
            if msgs:
                want[e[0].entity] = msgs
        res, _rejected = core.step(t, slots, np.array(xs), np.array(ys), 4.0)
        assert {ents[sl][1].entity: m for sl, m in res} == want, f"tick {k}"
    assert core.counters["vector_fixes"] > 0


def test_the_records_columns_and_the_fleets_own_names_do_not_collide():
    """The fleet core sets every record column as an attribute of its own (`_grow`): a record field named like
    one of its derived columns or attributes would silently replace it."""
    import inspect
    import re

    from entitynet.client import fleet as fleet_mod

    columns = set(FleetCore().rec.view())
    derived = {d[0] for d in fleet_mod._DERIVED} | set(fleet_mod._GHOST) | set(fleet_mod._CONST)
    assigned = set(re.findall(r"self\.(\w+)(?:\s*:[^=\n]*)?\s*=[^=]", inspect.getsource(FleetCore)))
    assert {"players", "rec", "counters", "deadline"} <= assigned | derived  # (the names are found)
    assert not columns & (derived | assigned | set(dir(FleetCore)))
