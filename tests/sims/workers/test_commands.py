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


def test_the_coordinator_silence_a_worker_waits_is_five_seconds_unless_told(capsys):
    """`sim worker --coordinator-silence` (default: the core's minimum, which its help names) takes 2 s or more:
    the coordinator says alive each second, so less would give live runs up."""
    from types import SimpleNamespace

    from entitynet.cli import build_parser
    from sims.workers.worker import SILENCE_MIN_S, WorkerCore

    parser = build_parser()
    base = ["sim", "worker", "--nats", "nats://127.0.0.1:4222"]
    assert parser.parse_args(base).coordinator_silence is None and SILENCE_MIN_S == 5.0
    assert parser.parse_args([*base, "--coordinator-silence", "2"]).coordinator_silence == 2.0
    for bad in ("1.9", "0", "nan", "inf"):
        with pytest.raises(SystemExit):
            parser.parse_args([*base, "--coordinator-silence", bad])
        assert "--coordinator-silence" in capsys.readouterr().err
    core = WorkerCore("w", "h", 1, build=None, silence_min=2.0)
    core.run, core.index, core.timeout, core.heard = "r", 0, 1.0, 10.0
    core.share = SimpleNamespace(counters=dict)  # (what `bye` carries)
    assert not core.expire(11.9) and core.expire(12.1)
    assert core.ended == "the coordinator was silent for over 2 s"


def test_the_nats_connect_timeout_is_one_second_unless_told(capsys):
    """`--nats-connect-timeout` on `sim` and `sim worker`: 1 s a try by default (as before the option), 0.1 to 60."""
    from entitynet.cli import build_parser

    parser = build_parser()
    for base in (["sim", "--nats", "nats://127.0.0.1:4222"], ["sim", "worker", "--nats", "nats://127.0.0.1:4222"]):
        assert parser.parse_args(base).nats_connect_timeout == 1.0
        assert parser.parse_args([*base, "--nats-connect-timeout", "0.1"]).nats_connect_timeout == 0.1
        for bad in ("0", "0.05", "61", "nan"):
            with pytest.raises(SystemExit):
                parser.parse_args([*base, "--nats-connect-timeout", bad])
            assert "--nats-connect-timeout" in capsys.readouterr().err
