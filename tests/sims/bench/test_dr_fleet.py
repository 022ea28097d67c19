"""`bench dr`'s network rows through the fleet core give what each entity stepped alone gives: every count of
the table (updates, the receiver's errors sample for sample, occupation, wrong edges, the publishes' reasons),
with and without the receiver's Doppler velocity, and the fixes' split between arrays and Players adds up."""

from __future__ import annotations

import random
from collections import Counter

import numpy as np
import pytest

from sims.bench.dr_bench import _new_acc, run_entity
from sims.bench.dr_data import SHARED, Entity, pedestrians, vehicles
from sims.bench.dr_fleet import run_fleet, split_summary


def _same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        if key == "errs":  # (per entity, in the entities' order: the table's mean sums them in that order)
            assert len(a[key]) == len(b[key])
            assert all(np.array_equal(x, y) for x, y in zip(a[key], b[key], strict=True))
        else:
            assert a[key] == b[key], key


@pytest.mark.parametrize("doppler", [None, 0.3])
def test_the_fleet_core_counts_what_each_entity_alone_counts(helsinki, doppler, gtfs_once):
    rng = random.Random(5)
    ents: list[Entity] = pedestrians(helsinki, 5, rng)
    if (SHARED / "hsl-gtfs-2022-02.zip").exists():
        ents += vehicles(helsinki, 3, rng, lambda _m: None)
    alone, together, split = _new_acc(), _new_acc(), Counter()
    for ent in ents:
        run_entity(helsinki, ent, "network", 5.0, alone, doppler=doppler)
    run_fleet(helsinki, ents, 5.0, together, doppler=doppler, split=split)
    assert alone["updates"] > 10 and alone["occ_n"] > 100
    _same(alone, together)
    s = split_summary(split)
    assert s["fixes"] == sum(int(e.t[-1] - e.t[0]) + 1 for e in ents)  # (a fix every second from 0)
    assert 0.3 < s["in_arrays"] < 1.0  # (the arrays did a share; placement and areas went to the Players)
    assert s["in_arrays"] + sum(s["scalar_by_reason"].values()) == pytest.approx(1.0, abs=1e-3)


def test_entities_off_the_grid_or_the_map_are_refused(helsinki):
    ent = pedestrians(helsinki, 1, random.Random(5))[0]
    shifted = Entity(ent.name, ent.etype, ent.t + 0.25, ent.xy, ent.cells)
    with pytest.raises(ValueError, match="grid"):
        run_fleet(helsinki, [ent, shifted], 5.0, _new_acc())
    with pytest.raises(ValueError, match="on the map"):
        run_fleet(helsinki, [Entity(ent.name, ent.etype, ent.t, ent.xy, None)], 5.0, _new_acc())
