"""SUMO against our world (the `sumo` rows of `bench sim`) on the small scenario: the figures are there and
consistent (their values are the benchmark's business), and the rows are a note without the extra."""

from __future__ import annotations

from sims.sumo import compare
from tests.sims.sumo.conftest import NEEDS_SUMO


def test_without_the_extra_the_rows_are_a_note(helsinki, monkeypatch):
    monkeypatch.setattr("sims.sumo.missing", lambda: "SUMO is not installed (libsumo)")
    rows = compare.bench_rows(helsinki, None, None, True, lambda m: None)
    assert rows == {"skipped": "SUMO is not installed (libsumo)"}


@NEEDS_SUMO
def test_step_cost_compares_the_same_number_of_cars(helsinki, small_scenario):
    r = compare.step_cost(helsinki, small_scenario.parent, 8, 4.0, slices=2)
    assert r["mean_cars"]["ours"] == 8 and 0 < r["mean_cars"]["sumo"] <= 8
    us = r["cpu_us_per_vehicle_s"]
    assert us["sumo"] > 0 and us["ours"] > 0 and r["ours_vs_sumo"] == us["ours"] / us["sumo"]
    split = r["ours_split_share"]
    assert abs(sum(split[k] for k in ("body_index", "decide", "after_move", "population", "rest")) - 1) < 1e-9
    assert split["decide_leader"] + split["decide_crossing"] <= split["decide"] + 1e-9


@NEEDS_SUMO
def test_end_to_end_runs_both_motions_with_the_same_mix(helsinki, small_scenario):
    r = compare.end_to_end(helsinki, small_scenario, 8.0, 3, 20.0)
    s, o = r["sumo"], r["ours"]
    assert s["mean_entities"] > 0 and o["mean_entities"] > 0
    assert s["entities"].get("car", 0) + s["entities"].get("pedestrian", 0) > 0
    assert s["updates_per_entity_min"] > 0 and o["updates_per_entity_min"] > 0
    assert s["off_network"]["entity_samples"] > 0 and "report" not in s


@NEEDS_SUMO
def test_client_split_tops_up_cars_and_walkers(helsinki, small_scenario):
    r = compare.client_split(helsinki, small_scenario.parent, 20, 2.0)
    assert r["mean_on_map"] > 0 and set(r["by_type"]) <= {"car", "pedestrian"}
    assert r["total_ms_per_tick"] == sum(r["ms_per_tick"].values()) and r["tick_ms"] == 500.0
