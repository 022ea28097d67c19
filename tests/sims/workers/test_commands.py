"""The worker daemon's `build`: a schedule per run read once, and at most one kept (a daemon serves run after run)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from sims.engine.sim import SimConfig
from sims.workers.commands import share_builder
from sims.workers.run import RefusedRun, config_to_wire, run_digests
from tests.sims.engine.test_routes import grid


class _Schedule:
    departures: list = []


def test_a_worker_daemon_keeps_one_schedule_however_many_runs_come(tmp_path):
    topo = grid()
    loads = []

    def load(feed, topo, date=None, cache=None, seed=0):
        loads.append(seed)
        return _Schedule()

    build = share_builder(topo, str(tmp_path / "feed.zip"), load=load)
    want = {**run_digests(topo, _Schedule()), "topology": "another map"}  # refused after the schedule is read
    config = SimConfig(entities=4, viewers=0, transit=True, start=0.0)
    for seed in (1, 1, 2, 3, 1):
        with pytest.raises(RefusedRun, match="another topology"):
            build(config_to_wire(replace(config, seed=seed)), want, 0, 1)
    assert loads == [1, 2, 3, 1]  # the same run again: read once; another: the one kept is replaced


def test_a_run_that_ended_early_exits_with_status_1_and_says_why():
    from types import SimpleNamespace

    from sims.sim_cmd import run_status

    said = []
    assert run_status(SimpleNamespace(ended_early=None), said.append) == 0
    assert run_status(SimpleNamespace(), said.append) == 0  # a one-process sim has no workers to lose
    assert not said
    assert run_status(SimpleNamespace(ended_early="every worker is gone (the last, worker 1, at tick 9)"),
                      said.append) == 1
    assert said == ["the run ended early: every worker is gone (the last, worker 1, at tick 9)"]
