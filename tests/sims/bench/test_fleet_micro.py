"""`sims.bench.fleet_micro`: the split adds up and counts every fix; the kernel A/B times every kernel it ran."""

from __future__ import annotations

import pytest

from entitynet.client import fleet_kernels
from sims.bench import fleet_micro


def test_split_parts_fit_in_the_step():
    r = fleet_micro.split(60, 3, 3)
    assert r["fixes"] > 100 and r["fixes_per_s"] > 0
    assert 0.0 < r["array_path_us"] < r["step_us"] and r["publish_us"] < r["step_us"]
    assert 0.5 < r["share_in_arrays"] <= 1.0


@pytest.mark.skipif(fleet_kernels.COMPILED is None, reason="the compiled fleet kernels were not built")
def test_kernels_are_timed_on_recorded_calls():
    r = fleet_micro.kernels(60)
    assert set(r) == {"project", "path_xy", "near", "s_of", "best_on"}
    assert r["path_xy"]["calls"] > 0 and r["near"]["calls"] > 0
    assert all(v["compiled_us_per_fix"] > 0 and v["numpy_us_per_fix"] > 0 for v in r.values() if v["calls"])
