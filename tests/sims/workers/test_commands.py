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
