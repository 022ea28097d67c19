"""The occupation-error breakdown (sims.bench.dr_causes) counts what bench dr counts, and classifies all of it."""

from __future__ import annotations

import random

from sims.bench import dr_causes
from sims.bench.dr_bench import _new_acc, run_entity
from sims.bench.dr_data import SHARED, pedestrians, vehicles


def test_breakdown_agrees_with_the_benchmark_and_classifies_every_bad_sample(helsinki, gtfs_once):
    rep = dr_causes.causes(helsinki, "pedestrians", progress=lambda _m: None, walkers=6)
    rng = random.Random(dr_causes.SEED)
    if (SHARED / "hsl-gtfs-2022-02.zip").exists():
        vehicles(helsinki, 36, rng, lambda _m: None)
    acc = _new_acc()
    for ent in pedestrians(helsinki, 6, rng):
        run_entity(helsinki, ent, "network", 5.0, acc)
    assert acc["occ_n"] > 0
    assert rep["occupation_error"] == acc["occ_bad"] / acc["occ_n"]
    bad = sum(rep["bad_samples_by_cause"].values())
    assert bad == acc["occ_bad"]
    assert sum(e["samples"] for e in rep["largest_episodes"]) <= bad
    for cause in rep["bad_samples_by_cause"]:
        where, _reason, model = cause.split(" / ")
        assert where in {"expired", "front", "aft", "mid", "body"} and model in {"standing model", "moving model"}


def test_a_fixed_look_ahead_is_taken_and_reported(helsinki, monkeypatch, gtfs_once):
    given = []

    class Recording(dr_causes.Player):
        def __init__(self, *args, **kw):
            given.append(kw.get("lookahead", "default"))
            super().__init__(*args, **kw)

    monkeypatch.setattr(dr_causes, "Player", Recording)
    rep = dr_causes.causes(helsinki, "pedestrians", lookahead=0.0, progress=lambda _m: None, walkers=2)
    assert rep["params"]["lookahead_m"] == 0.0
    assert given and set(given) == {0.0}  # every replayed client got the fixed look-ahead
    assert 0.0 <= rep["occupation_error"] <= 1.0
    given.clear()
    dr_causes.causes(helsinki, "pedestrians", progress=lambda _m: None, walkers=2)
    assert given and set(given) == {"default"}  # and without one, the client's own rule
