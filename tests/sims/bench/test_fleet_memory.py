"""`sims.bench.fleet_memory` (issue 22): the bytes per tracked entity come from the client code's allocations,
and the growth run counts a Player kept alive after its entity left (a leak) where there is one, and none
where there is not."""

from __future__ import annotations

import pytest

from sims.bench import fleet_memory
from sims.engine import clients


def test_a_short_run_states_bytes_per_entity_above_the_row_and_no_leak(helsinki):
    rep = fleet_memory.measure(helsinki, entities=40, seconds=12, samples=3, traced_seconds=4)
    assert rep["row_bytes"] == rep["traced"]["row_bytes"] > 0
    # a Player and its parts are Python objects on top of the record's row
    assert rep["bytes_per_entity"] > rep["row_bytes"]
    assert rep["traced"]["tracked"] > 0 and "player.py" in rep["traced"]["by_file"]
    assert rep["players_leaked"] == 0
    rows = rep["growth"]["samples"]
    assert [r["t_s"] for r in rows] == [4, 8, 12]
    assert all(r["players_alive"] == r["tracked"] > 0 for r in rows)
    # every interval between samples stepped the fleet and counted its fixes
    assert all(r["fleet_fixes_per_s"] > 0 for r in rows)
    assert rep["growth"]["fleet_fixes_per_s_first"] == rows[0]["fleet_fixes_per_s"]
    assert min(r["fleet_fixes_per_s"] for r in rows) <= rep["growth"]["fleet_fixes_per_s_median"] <= max(
        r["fleet_fixes_per_s"] for r in rows)
    assert rep["growth"]["fleet_fixes_per_s_last"] == rows[-1]["fleet_fixes_per_s"]


def test_a_leaked_player_is_counted(helsinki, monkeypatch):
    """Removed entities' Players kept in a list (as a cache keyed by entity would keep them) show as leaked."""
    kept: list = []
    remove = clients.FleetCore.remove

    def keeping(self, slot):
        kept.append(self.players[slot])
        return remove(self, slot)

    monkeypatch.setattr(clients.FleetCore, "remove", keeping)
    rep = fleet_memory.growth(helsinki, entities=60, seconds=90, samples=2)
    assert kept, "no entity left in 90 s: the test needs a run in which some do"
    assert rep["players_leaked"] >= len(kept) > 0


def test_bad_sizes_are_refused(helsinki):
    for kw in ({"entities": 0}, {"seconds": 1}, {"samples": 1}, {"traced_seconds": 0}):
        with pytest.raises(ValueError):
            fleet_memory.measure(helsinki, **{"entities": 5, "seconds": 4, "samples": 2, "traced_seconds": 1, **kw})


def test_the_command_refuses_bad_sizes_in_one_line(capsys):
    with pytest.raises(SystemExit) as e:
        fleet_memory.main(["--entities", "0"])
    assert e.value.code == 2
    assert "--entities >= 1" in capsys.readouterr().err
