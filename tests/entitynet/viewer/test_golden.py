"""The committed golden vectors of the JavaScript extrapolation test are what the Python client writes today."""

from __future__ import annotations

import json

from tests.entitynet.viewer.golden import OUT, golden_vectors


def test_golden_vectors_are_current():
    committed = json.loads(OUT.read_text())
    fresh = json.loads(json.dumps(golden_vectors()))
    assert committed == fresh, "stale golden vectors: run `python -m tests.entitynet.viewer.golden`"


def test_golden_vectors_exercise_the_limits():
    g = golden_vectors()
    horizon = g["limits"]["horizon"]
    # some cases are evaluated past the horizon and before t0, where the limits decide the answer
    for case in g["cases"]:
        t0 = case["times"][1]  # DTS[1] == 0.0
        assert min(case["times"]) < t0 < t0 + horizon < max(case["times"]), case["name"]
