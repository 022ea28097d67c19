"""`python -m sims.bench.e2e_errors`'s distribution: quantiles and a histogram that covers every sample,
hostile values included (an empty group, inf, huge errors)."""

from __future__ import annotations

import math

from sims.bench.e2e_errors import distribution


def test_an_empty_group_has_no_quantiles():
    assert distribution([]) == {"samples": 0}


def test_quantiles_and_a_histogram_that_sums_to_one():
    d = distribution([0.5, 1.5, 2.5, 9.5, 11.0, 100.0, 1e12])
    assert d["samples"] == 7 and d["max_m"] == 1e12 and d["p50_m"] == 9.5
    assert math.isclose(sum(d["histogram"].values()), 1.0, abs_tol=1e-3)
    assert d["histogram"]["0-1"] == round(1 / 7, 4)
