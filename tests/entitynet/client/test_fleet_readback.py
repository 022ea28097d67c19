"""The fleet core's read-back after a scalar call (`FleetCore._load`, issue 11): it reads what a call can
change (the filter, the fixes, the path) every time, the published ghost only when a publish made a new one,
and the entity's constants once; `player(slot)` hands the Player out, so the next read-back reads it all.
And a fix whose path must be extended ahead no longer leaves the arrays for it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from entitynet.client.fleet import _C0, _F, _G0
from tests.entitynet.client.test_fleet import _run
from tests.entitynet.client_fixtures import chain, cross, parallel


def _fast_slot(core) -> int:
    slots = [s for s in range(len(core.players)) if core.players[s] is not None and core.fast[s]]
    assert slots, "no entity on the vectorised path"
    return slots[0]


def test_read_back_skips_the_unchanged_ghost_and_constants():
    _a, _b, core, _ents = _run(parallel(gap=12.0, length=300.0), n=6, ticks=60)
    s = _fast_slot(core)
    row = core.fm[s].copy()
    core.fm[s, _G0:] = -7.0  # sentinels: a read-back of an unchanged ghost and of the constants keeps them
    core.fm[s, :_G0] = -7.0
    core._load(s)
    assert np.array_equal(core.fm[s, :_G0], row[:_G0])  # the changing fields are read every time
    assert (core.fm[s, _G0:] == -7.0).all()
    # handing the Player out reads it all again: the ghost and the constants come back
    core.player(s)
    core._load(s)
    assert np.array_equal(core.fm[s], row)


def test_a_new_ghost_and_a_changed_constant_are_read():
    _a, _b, core, _ents = _run(parallel(gap=12.0, length=300.0), n=6, ticks=60)
    s = _fast_slot(core)
    p = core.player(s)
    p.rules.threshold = 123.0  # a change made through the handed-out Player
    core._load(s)
    assert core.fm[s, _F.index("thr")] == 123.0
    # a publish (here: the fix gap's, `max_gap` after the last fix) makes a new ghost: its columns follow it
    ghost = p.ghost
    msgs = p.tick(min(p.last_t + p.rules.max_gap, p.pub_t + p.rules.validity(p.occupation)))
    assert msgs and p.ghost is not ghost
    core._load(s)
    assert core.fm[s, _F.index("pub_t")] == p.pub_t
    assert core.fm[s, _F.index("g_t0")] == p.ghost.t0 and core.fm[s, _F.index("g_s0")] == p.ghost.s0
    assert math.isfinite(core.fm[s, _C0])


@pytest.mark.parametrize("topo", [parallel(gap=12.0, length=300.0), chain(), cross(arm=100.0)])
def test_paths_extended_in_arrays_give_the_players_messages_and_state(topo):
    """A fix whose path needs extending ahead (`_maintain_path`) stays in arrays: the edges `follow` gives are
    appended row by row (a dead end is remembered); the messages and the written-back paths are the twins'."""
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
