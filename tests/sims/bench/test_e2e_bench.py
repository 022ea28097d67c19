"""The e2e suite's bookkeeping around its runs (the runs themselves are in test_e2e_run.py)."""

from __future__ import annotations

from sims.bench.e2e_bench import SYSTEMS, with_idle
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
