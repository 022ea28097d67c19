"""The ladder as `entitynet bench switch` drives it (sims/bench/switch_bench.py `run`): climbing, descending for a
system that qualified nowhere above, bisecting each system's bracket, and the capacities and ratios that come
out, with the servers and the load replaced by a model whose capacities are known.

Why: a real ladder takes about 14 minutes and its outcome depends on the machine, so the order of the steps
and the arithmetic of the verdicts are checked here against a model: a system with capacity C (entities)
delivers what is offered, at p99 50 ms up to C, 500 ms up to 2C, and 3 s (past saturation) beyond.
"""

from __future__ import annotations

import argparse
from contextlib import contextmanager
from types import SimpleNamespace

import pytest

from sims.bench import switch_bench

CAPACITY = {"entitynet": 11_000, "redis": 15_000, "nats": 700}
PER_ENTITY = 50.0  # deliveries/s per entity in the model


@pytest.fixture
def modelled(monkeypatch):
    """`run` with its servers, load and topology replaced; returns the list of (system, entities) run."""
    ran: list[tuple[str, int]] = []
    topo = SimpleNamespace(digest="d" * 64, n_cells=4)

    @contextmanager
    def fake_started(system, exe, topo_path, digest, p, plan, log_dir, progress):
        yield SimpleNamespace(name=system), SimpleNamespace(pid=0), None

    def fake_load(driver, proc, walkers_factory, view_cells, p, progress, scrape=None, offered=None):
        system, n = driver.name, p["entities"]
        ran.append((system, n))
        cap = CAPACITY[system]
        p99 = 50.0 if n <= cap else 500.0 if n <= 2 * cap else 3000.0
        rate = n * PER_ENTITY
        return {"deliveries_per_s": rate, "offered_deliveries_per_s": rate, "latency_p50_ms": p99 / 2,
                "latency_p99_ms": p99, "cpu_s_per_million_deliveries": 1.0, "rss_bytes_per_entity": 0.0,
                "updates_in_per_s": n / 10, "loadgen_max_tick_lateness_ms": 0.0}

    import topology.artifact

    monkeypatch.setattr(switch_bench, "started", fake_started)
    monkeypatch.setattr(switch_bench, "_run_load", fake_load)
    monkeypatch.setattr(switch_bench, "find_exe", lambda name, pkg, progress: (f"/bin/{name}", "fake"))
    monkeypatch.setattr(switch_bench, "usable_cores", lambda: [0, 1])
    monkeypatch.setattr(switch_bench, "_topology_path", lambda args, progress, quick: "t.enttopo")
    monkeypatch.setattr(switch_bench, "_view_cells", lambda topo, n, p, notes, progress: [(0, 1)] * n)
    monkeypatch.setattr(topology.artifact, "load", lambda path: topo)
    return ran


def test_the_full_ladder_climbs_descends_and_bisects_each_bracket(modelled):
    body = switch_bench.run(argparse.Namespace(quick=False, topology=None), lambda msg: None)
    ran = modelled
    per = {s: [n for sys_, n in ran if sys_ == s] for s in CAPACITY}
    # ours: qualifies at 10,000; 20,000 is late but not past saturation, 40,000 is; then the bracket
    # (10,000, 20,000) halves twice, geometrically, and neither middle qualifies
    assert per["entitynet"] == [5000, 10_000, 20_000, 40_000, 14_140, 11_890]
    # Redis: the same climb; then 14,140 qualifies and 16,820 does not
    assert per["redis"] == [5000, 10_000, 20_000, 40_000, 14_140, 16_820]
    # NATS: past saturation at the standard load, qualifies first at 625 on the way down, then bisects
    assert per["nats"] == [5000, 2500, 1250, 625, 880, 740]
    r = body["results"]
    assert r["capacity_deliveries_per_s"] == 10_000 * PER_ENTITY
    assert r["redis_capacity_deliveries_per_s"] == 14_140 * PER_ENTITY
    assert r["nats_capacity_deliveries_per_s"] == 625 * PER_ENTITY
    assert r["capacity_ratio_vs_redis"] == pytest.approx(10_000 / 14_140)
    assert r["capacity_ratio_vs_nats"] == pytest.approx(10_000 / 625)
    assert body["params"]["refine_rounds"] == 2
    for rows in body["ladder"].values():  # the report lists each system's steps in order of load
        assert [row["entities"] for row in rows] == sorted(row["entities"] for row in rows)


def test_the_quick_run_is_one_step_and_no_bisection(modelled):
    body = switch_bench.run(argparse.Namespace(quick=True, topology=None), lambda msg: None)
    assert modelled == [("entitynet", 2000), ("redis", 2000), ("nats", 2000)]
    assert body["params"]["refine_rounds"] == 0
