"""The sim bench suite's figures on a tiny run (their presence and consistency, not their values)."""

from __future__ import annotations

import pytest

from sims.bench.sim_bench import _per_viewer_s
from sims.engine.local import run_local
from sims.engine.sim import Sim, SimConfig
from tests.sims.engine.test_routes import grid


def test_per_viewer_rates_split_street_and_roof():
    sim = Sim(grid(), SimConfig(entities=10, viewers=4, roof_share=0.5, transit=False, start=0.0,
                                subscribe="radius", radius=400.0))
    run_local(sim, 10.0)
    street = _per_viewer_s(sim, 10.0, high=False)
    roof = _per_viewer_s(sim, 10.0, high=True)
    total = sum(v.deliveries for v in sim.viewers)
    assert street["deliveries"] * 2 * 10.0 + roof["deliveries"] * 2 * 10.0 == total
    assert street["bytes"] > 0 and street["messages"] >= street["deliveries"]


def test_fleet_rates_measure_both_cores_in_one_run():
    from sims.bench.sim_bench import _fleet_rates

    r = _fleet_rates(grid(), 20, 3, 2)  # (asserts the two fleets' messages equal every tick)
    assert r["fleet"] > 0 and r["player"] > 0 and r["ratio"] == r["fleet"] / r["player"]
    assert 0.0 < r["share"] <= 1.0  # the fleet run's arrays decided some fixes (the baseline's none)
    assert "warm" not in r


def test_fleet_rates_time_a_second_window_of_the_same_run():
    from sims.bench.sim_bench import _fleet_rates

    r = _fleet_rates(grid(), 20, 3, 2, warm=8)
    w = r["warm"]
    assert (r["after_s"], w["after_s"]) == (2, 8)
    assert w["fleet"] > 0 and w["player"] > 0 and w["ratio"] == w["fleet"] / w["player"]
    assert 0.0 < w["share"] <= 1.0
    # a second window that would overlap the first is not taken
    assert "warm" not in _fleet_rates(grid(), 20, 3, 2, warm=4)
    with pytest.raises(ValueError, match="at least 1 simulated s"):
        _fleet_rates(grid(), 20, 0, 2)
