"""`sims.bench.publish_cost` (issue 22): the figures it gives, the collections timed apart, and the same digest of the
messages on a second run (a small run: the command's own figures are a benchmark's, not a test's)."""

from __future__ import annotations

import math

from sims.bench.publish_cost import measure


def test_a_small_run_gives_every_figure_and_the_collections_apart():
    out = measure(entities=60, warmup=2, seconds=4)
    assert out["publishes"] > 0 and len(out["digest"]) == 16
    assert 0.0 < out["publish_us_without_gc"] <= out["publish_us"]
    assert 0.0 < out["fleet_us_per_entity_step_without_gc"] <= out["fleet_us_per_entity_step"]
    assert out["gc_ms_in_fleet"] >= 0.0 and len(out["gc_collections"]) == 3
    assert all(isinstance(n, int) and n >= 0 for n in out["gc_collections"])
    assert math.isfinite(out["publish_share_of_fleet"])
    assert measure(entities=60, warmup=2, seconds=4)["digest"] == out["digest"]  # the same messages again
