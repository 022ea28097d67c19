"""`sims.bench.publish_together` (issue 22): every pass times the tick's publishers' covers, and the covers made
again, in another order and twice at once equal the first (the command raises otherwise)."""

from __future__ import annotations

import math

import pytest

from sims.bench.publish_together import measure


def test_a_small_run_times_every_pass_on_the_same_covers():
    out = measure(entities=60, warmup=2, seconds=3)
    assert out["covers"] > 0
    med = out["median_us_per_cover"]
    assert set(med) == {"together", "together_again", "by_edge", "first", "again"}
    assert all(math.isfinite(v) and v > 0.0 for v in med.values())
    ticks = {len(v) for v in out["per_tick_us"].values()}
    assert len(ticks) == 1 and ticks.pop() >= 1  # the same ticks in every pass


def test_bounds_are_checked():
    with pytest.raises(ValueError):
        measure(entities=0)
    with pytest.raises(ValueError):
        measure(entities=10, seconds=0)
