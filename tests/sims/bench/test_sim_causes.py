"""The instrumented run behind docs/simulation.md's breakdown (issue 11): every delivery to a street viewer is
counted once under each split, and the splits add up to what the viewers themselves counted."""

from __future__ import annotations

import pytest

from sims.bench.sim_causes import instrumented_run
from sims.engine.sim import SimConfig
from tests.sims.engine.test_routes import grid


def test_the_splits_add_up_to_the_viewers_deliveries():
    cfg = SimConfig(entities=12, viewers=3, connections=2, subscribe="radius", radius=150.0, transit=False,
                    start=0.0, roof_share=0.0, seed=4)
    rep = instrumented_run(grid(), None, cfg, 20.0)
    total = rep["deliveries_per_viewer_s"]
    r = rep["by_reason_per_viewer_s"]
    assert total > 0
    assert r["live"] + r["snapshot"] == pytest.approx(total)
    assert r["in_view"] + r["ahead_then_in_view"] + r["ahead_never_in_view"] == pytest.approx(total)
    assert sum(rep["by_type_per_viewer_s"].values()) == pytest.approx(total)
    assert sum(rep["cells_per_update"].values()) == pytest.approx(1.0)
    assert r["duplicate"] == 0.0  # the switchboard forwards one update once
    assert rep["subscribe_per_viewer_s"]["messages"] > 0  # the first subscription at least
    assert 0.0 < rep["radius_disc_on_map"] <= 1.0
