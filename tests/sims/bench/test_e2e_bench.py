"""The e2e suite's bookkeeping around its runs (the runs themselves are in test_e2e_run.py)."""

from __future__ import annotations

import pytest

from sims.bench.e2e_bench import STABILITY, SYSTEMS, summarise, targets, with_idle
from sims.bench.e2e_run import RunParams

BY_NAME = {s.name: s for s in SYSTEMS}


def _recording(cpu_by_entities: dict[int, float]):
    seen: list[RunParams] = []

    def run_at(params: RunParams) -> dict:
        seen.append(params)
        return {"server_cpu_ms_per_viewer_s": cpu_by_entities[params.entities]}
    return seen, run_at


def test_the_idle_run_goes_at_the_real_runs_speed_and_is_subtracted():
    """The servers' wall-clock loops cost per wall second: an idle run at another speed than the real one would
    measure them over another length of time, and the net figure would be biased."""
    p = RunParams(entities=400, viewers=30, seconds=60.0, speed=1.5)
    seen, run_at = _recording({400: 5.0, 0: 1.25})
    rep = with_idle(BY_NAME["mqtt-disc"], p, run_at)
    assert [s.entities for s in seen] == [400, 0]
    real, idle = seen
    assert (idle.speed, idle.seconds, idle.viewers) == (real.speed, real.seconds, real.viewers)
    assert not idle.transit
    assert rep["server_cpu_idle_ms_per_viewer_s"] == 1.25 and rep["server_cpu_net_ms_per_viewer_s"] == 3.75


def test_systems_without_an_idle_pass_run_once():
    seen, run_at = _recording({400: 5.0})
    rep = with_idle(BY_NAME["entitynet-radius"], RunParams(entities=400), run_at)
    assert len(seen) == 1 and "server_cpu_net_ms_per_viewer_s" not in rep


def _rep(cpu_ms: float, loadgen_s: float, bytes_: float = 1000.0) -> dict:
    """One repetition's figures as `run_system` reports them (only what the summary reads)."""
    return {"messages_per_viewer_s": 20.0, "bytes_per_viewer_s": bytes_, "error_p95_m": 9.0,
            "server_cpu_ms_per_viewer_s": cpu_ms, "loadgen_cpu_s": loadgen_s,
            "server_cpu_per_loadgen_cpu": cpu_ms / loadgen_s}


def test_a_machine_that_slows_for_one_repetition_fails_the_raw_check_not_the_normalised_one():
    """The third repetition 40 % dearer for the broker and for the load generator alike (what the VM did in
    docs/e2e-bench-round10-first.json): the raw spread is 40 %, the work-normalised one nil."""
    s = summarise({"x": [_rep(1.0, 10.0), _rep(1.0, 10.0), _rep(1.4, 14.0)]})["x"]
    assert s["server_cpu_ms_per_viewer_s_spread"] == pytest.approx(0.4)
    assert s["loadgen_cpu_s_spread"] == pytest.approx(0.4)
    assert s["server_cpu_per_loadgen_cpu_spread"] == pytest.approx(0.0)
    assert not s["stable"] and s["stable_work_normalised"]


def test_a_broker_that_alone_gets_dearer_fails_both_checks():
    """The load generator's CPU the same, the broker's 30 % up in one repetition: the broker's own change, which
    the normalised figure must not hide."""
    s = summarise({"x": [_rep(1.0, 10.0), _rep(1.0, 10.0), _rep(1.3, 10.0)]})["x"]
    assert s["server_cpu_per_loadgen_cpu_spread"] == pytest.approx(0.3)
    assert s["server_cpu_per_loadgen_cpu_spread"] > STABILITY
    assert not s["stable"] and not s["stable_work_normalised"]


def test_bytes_that_move_fail_the_normalised_check_too():
    s = summarise({"x": [_rep(1.0, 10.0), _rep(1.0, 10.0, 1500.0), _rep(1.0, 10.0)]})["x"]
    assert not s["stable_work_normalised"]


def test_the_targets_report_both_checks_and_how_far_the_machine_moved():
    runs = {"entitynet": [_rep(0.2, 5.0), _rep(0.2, 5.0), _rep(0.3, 7.5)],
            "mqtt-disc": [_rep(1.2, 15.0, 28000.0)] * 3}
    for r in runs["entitynet"]:
        r["server_cpu_net_ms_per_viewer_s"] = None
    tg = targets(summarise(runs), runs)
    assert not tg["every_system_stable_15pct"] and tg["every_system_stable_15pct_work_normalised"]
    assert tg["loadgen_cpu_spread_max"] == pytest.approx(0.5)


def test_a_run_without_load_generator_cpu_gives_no_normalised_figure():
    rep = _rep(1.0, 10.0)
    rep["server_cpu_per_loadgen_cpu"] = None
    s = summarise({"x": [rep]})["x"]
    assert s["server_cpu_per_loadgen_cpu"] is None
