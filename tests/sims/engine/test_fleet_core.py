"""The simulation's honest clients through the fleet core and through per-entity Players: the same messages.

`Fleet(core="fleet")` draws the GPS noise of a tick in one call and steps the client cores over arrays; with the
same seed it must send exactly what `core="player"` sends, tick by tick and connection by connection (the grid
with two ticks per fix, so the timers run between fixes; the bundled Helsinki map, where most fixes of short
edges take the scalar path).
"""

from __future__ import annotations

import pytest

from sims.engine.clients import Fleet
from sims.engine.sim import Sim, SimConfig
from tests.sims.engine.test_routes import grid


def _both(topo, ticks: int, **kw) -> tuple[Sim, Sim]:
    sims = [Sim(topo, SimConfig(viewers=0, seed=4, core=core, **kw)) for core in ("player", "fleet")]
    a, b = sims[0].start()[0], sims[1].start()[0]
    assert a == b
    for k in range(ticks):
        a, b = sims[0].step()[0], sims[1].step()[0]
        assert a == b, f"tick {k}: the fleet core's messages differ"
    assert sims[0].fleet.counters == sims[1].fleet.counters
    return sims[0], sims[1]


def test_grid_fleet_core_sends_what_the_players_send():
    _p, f = _both(grid(), 120, entities=30, tick_hz=2.0, transit=False, start=0.0)
    c = f.fleet.fleet_core.counters
    assert c["vector_fixes"] > 0.3 * (c["vector_fixes"] + c["scalar_fixes"])
    assert c["vector_near"] > 0 and c["vector_trims"] > 0  # the neighbourhood search and path trims in arrays
    assert f.fleet.counters["published"] > 30
    # every scalar fix is counted once under the first reason that sent it there; publishes are decided in
    # arrays (the Player builds them)
    why = f.fleet.fleet_core.scalar_why
    assert sum(why.values()) == c["scalar_fixes"] and c["vector_publishes"] > 0, (why, c)
    # the per-entity baseline is the same core with its arrays off: every fix and tick one by one
    base = _p.fleet.fleet_core.counters
    assert base["vector_fixes"] == 0 and base["scalar_fixes"] == _p.fleet.counters["fixes"]
    assert _p.fleet.fleet_core.scalar_why["not_vectorised"] == base["scalar_fixes"]


def test_helsinki_fleet_core_sends_what_the_players_send(helsinki):
    _p, f = _both(helsinki, 24, entities=60, tick_hz=2.0, transit=False)
    assert f.fleet.fleet_core.counters["vector_fixes"] > 20


def test_the_core_is_chosen_by_name():
    with pytest.raises(ValueError, match="core must be"):
        SimConfig(core="numpy")
    with pytest.raises(ValueError, match="core must be"):
        Fleet(Sim(grid(), SimConfig(viewers=0, transit=False)).world, core="numpy")
    assert Sim(grid(), SimConfig(viewers=0, transit=False)).fleet.core == "fleet"
