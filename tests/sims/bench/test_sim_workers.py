"""The worker rows of `bench sim`: present and consistent on a tiny run (not their values), and the model."""

from __future__ import annotations

import pytest

from sims.bench.sim_workers import model_entities, worker_rows
from tests.sims.engine.test_routes import grid


@pytest.fixture(scope="module")
def quick_rows() -> dict:
    """One --quick run of the worker rows (three runs in subprocess workers: seconds), read by two tests."""
    return worker_rows(grid(), None, True, lambda m: None, entities=12, viewers=2, transit=False)


def test_worker_rows_time_every_mode_on_the_same_run(quick_rows):
    r = quick_rows
    assert [x["workers"] for x in r["runs"]] == [0, 1, 2]
    assert len({x["entities_on_map"] for x in r["runs"]}) == 1  # the same truth in every mode
    assert r["two_vs_one_worker"] == r["wall_s_median"]["two_workers"] / r["wall_s_median"]["one_worker"]
    assert len(r["runs"][2]["worker_step_p50_ms"]) == 2
    assert all(v > 0 for v in r["cost_per_entity_tick_us"].values())
    assert [m["machines"] for m in r["model"]] == [1, 2, 4, 8]


def test_the_model_puts_the_limit_where_the_costs_are():
    cost = {"world": 10.0, "clients": 80.0, "coordinator": 30.0}  # microseconds per entity-tick
    one = model_entities(cost, 1)
    assert one["worker_bound"] == pytest.approx(0.5e6 / 90.0) and one["limited_by"] == "workers"
    eight = model_entities(cost, 8)
    assert eight["coordinator_bound"] == pytest.approx(0.5e6 / 40.0) and eight["limited_by"] == "coordinator"
    assert eight["entities"] == eight["coordinator_bound"]


def test_quick_skips_the_realtime_trials_and_a_trial_runs_with_workers_over_sockets(quick_rows, tmp_path):
    from sims.bench.sim_workers import realtime_trial
    from topology.artifact import save

    assert quick_rows["realtime"] == "skipped with --quick"
    path = tmp_path / "grid.enttopo"
    topo = grid()
    save(topo, path)
    trial = realtime_trial(topo, path, None, 2, 6, 1, 1.0, warmup_ticks=2)
    assert trial["workers"] == 2 and trial["tick_lateness_p99_ms"] >= 0 and isinstance(trial["ok"], bool)
