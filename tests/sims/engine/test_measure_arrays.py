"""The truth measure over arrays (issue 23) counts what the per-entity measure counted: the same visible,
missed, shown and stale counts and the same errors (as a multiset: the order of the list may differ)."""

from __future__ import annotations

import math
from collections import defaultdict

import pytest

from sims.engine.local import LocalSwitch
from sims.engine.measure import Measure, Tally
from sims.engine.sim import Sim, SimConfig


def reference_sample(tallies, now, world, viewers, eid_to_agent) -> None:
    """The measure as it was written per entity (sets and dicts), the reference the arrays are held to."""
    where: dict[int, list[int]] = defaultdict(list)
    truth, cells_of = {}, {}
    for a in world.agents.values():
        truth[a.id] = a.xy()
        cells_of[a.id] = cs = a.cells()
        for c in cs:
            where[c].append(a.id)
    for v in viewers:
        t = tallies["roof" if v.high else "street"]
        t.viewer_samples += 1
        inside: set[int] = set()
        for c in v.subs.cells:
            inside.update(where.get(c, ()))
        shown, claimed = {}, {}
        drawn = v.ghosts.positions(now)  # the store's own API: each viewer's ghosts one by one
        held = v.ghosts.ghosts
        for eid, xy in drawn.items():
            cells = held[eid].cells
            aid = eid_to_agent.get(eid, -1)
            if aid < 0:
                continue
            shown[aid] = xy
            claimed[aid] = cells
        t.visible += len(inside)
        t.shown += len(shown)
        for aid in inside:
            g = shown.get(aid)
            if g is None:
                t.missed += 1
            else:
                t.errors.append(math.hypot(g[0] - truth[aid][0], g[1] - truth[aid][1]))
        for aid in shown:
            if aid not in inside and not set(cells_of.get(aid, ())) & set(claimed[aid]):
                t.stale += 1


def _compare(ours: Measure, ref: dict[str, Tally]) -> None:
    assert set(ours.tallies) == set(ref)
    for k, t in ours.tallies.items():
        r = ref[k]
        assert (t.visible, t.missed, t.shown, t.stale, t.viewer_samples) == \
               (r.visible, r.missed, r.shown, r.stale, r.viewer_samples), k
        assert sorted(t.errors) == sorted(r.errors), k


@pytest.mark.parametrize("subscribe", ["radius", "pvs"])
def test_the_array_measure_counts_what_the_per_entity_measure_counted(helsinki, subscribe):
    sim = Sim(helsinki, SimConfig(entities=120, viewers=8, connections=2, tick_hz=2.0, transit=False, seed=6,
                                  subscribe=subscribe, radius=300.0, measure_after=1.0))
    ref: dict[str, Tally] = defaultdict(Tally)
    sample = sim.measure.sample

    def both(now, world, viewers, eid_to_agent):
        reference_sample(ref, now, world, viewers, eid_to_agent)
        sample(now, world, viewers, eid_to_agent)

    sim.measure.sample = both
    sw = LocalSwitch(sim)
    sw.exchange(*sim.start())
    ids = sw.eid_to_agent()
    for k in range(60):
        sw.exchange(*sim.step())
        ids = sw.eid_to_agent()
        if k == 40:  # an entity the switchboard still has but the world has removed, and an unknown id
            gone = max(ids.values()) + 10_000
            ids = {**ids, next(iter(ids)): gone}
        if k >= 50:  # two entity ids of one agent (a re-published entity): the later ghost's position counts
            e1, e2 = sorted(ids)[:2]
            ids = {**ids, e2: ids[e1]}
        sim.maybe_sample(ids)
    m = sim.measure
    assert m.tallies["street"].visible > 200 and m.tallies["street"].missed > 0
    assert sum(t.stale for t in ref.values()) > 0 or subscribe == "pvs"
    _compare(m, ref)


def test_a_sample_at_a_time_that_is_not_finite_is_refused(helsinki):
    sim = Sim(helsinki, SimConfig(entities=5, viewers=2, transit=False, subscribe="radius"))
    with pytest.raises(ValueError):
        sim.measure.sample(float("nan"), sim.world, sim.viewers, {})


def test_cells_outside_the_map_count_as_the_per_entity_measure_counts_them():
    # a subscription naming a cell id below zero or past the map, and a body of another source that says it is
    # in such a cell: a cell id is only ever equal to itself (no clipping onto cell 0 or wrapping to the end)
    from types import SimpleNamespace

    class Body:
        def __init__(self, i, cells):
            self.id, self._cells = i, cells

        def xy(self):
            return (float(self.id), 0.0)

        def cells(self):
            return self._cells

    world = SimpleNamespace(topo=SimpleNamespace(n_cells=4), net=None,
                            agents={1: Body(1, (0,)), 2: Body(2, (3,)), 3: Body(3, (-2,)), 4: Body(4, (-1, 2))})
    from entitynet.client import GhostStore

    viewers = [SimpleNamespace(high=False, subs=SimpleNamespace(cells=frozenset(s)), ghosts=GhostStore(None))
               for s in ({-1}, {-3}, {7}, {-2}, {3, -5}, {2, 9})]
    ours, ref = Measure(), defaultdict(Tally)
    ours.sample(10.0, world, viewers, {})
    reference_sample(ref, 10.0, world, viewers, {})
    _compare(ours, ref)
    assert ref["street"].visible == 4  # -1 sees body 4, -2 body 3, 3 body 2, 2 body 4


def test_claims_met_by_one_sort_counts_what_the_pairs_say():
    """`_claims_met` (one sort of (ghost, cell, side) as an integer; lexsort where the integer would overflow)
    against the plain count: a ghost meets its claim when one of its claimed cells is one its entity occupies."""
    import random

    import numpy as np

    from sims.engine import measure as M
    from sims.engine.truth_arrays import TruthArrays

    class Table:
        def __init__(self, claims):
            self.voff = np.concatenate([[0], np.cumsum([len(c) for c in claims])]).astype(np.int64)
            self.vcells = np.array([c for cs in claims for c in cs], dtype=np.int64)

    rng = random.Random(2)
    for trial in range(200):
        lo, hi = (-2**60, 2**60) if trial % 5 == 0 else (-3, 40)  # (spans past the one-integer key: lexsort)

        def pick(lo=lo, hi=hi):
            return rng.randint(lo, hi)
        truth_cells = [sorted({pick() for _ in range(rng.randint(1, 4))}) for _ in range(rng.randint(0, 12))]
        claims = [[pick() for _ in range(rng.randint(0, 5))] for _ in range(rng.randint(0, 15))]
        truth = TruthArrays(np.arange(len(truth_cells)), np.zeros(len(truth_cells)), np.zeros(len(truth_cells)),
                            np.concatenate([[0], np.cumsum([len(c) for c in truth_cells])]).astype(np.int64),
                            np.array([c for cs in truth_cells for c in cs], dtype=np.int64))
        versions = np.array(rng.sample(range(len(claims)), rng.randint(0, len(claims))), dtype=np.int64)
        rows = np.array([rng.randrange(-1, len(truth_cells)) if truth_cells else -1 for _ in versions],
                        dtype=np.int64)
        want = sum(1 for v, r in zip(versions.tolist(), rows.tolist(), strict=True)
                   if r >= 0 and set(claims[v]) & set(truth_cells[r]))
        assert M._claims_met(Table(claims), versions, truth, rows) == want, trial
        a = np.sort(np.array([rng.randint(0, 9) for _ in range(rng.randint(0, 30))], dtype=np.int64))
        assert M._distinct_sorted(a).tolist() == np.unique(a).tolist()
