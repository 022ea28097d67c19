"""The truth as arrays (issue 23, the measure over arrays): bit for bit what each entity's `xy()` and `cells()`
give, for walkers, cars, area walks and bodies of another source; the edge lookups against `NetView`."""

from __future__ import annotations

import random

import numpy as np
import pytest

from sims.engine.population import Population, PopulationConfig
from sims.engine.routes import Router
from sims.engine.truth_arrays import EdgeArrays, truth_arrays
from sims.engine.world import World
from topology.raw import TRAM


def _world(topo, seconds: float = 90.0, entities: int = 300) -> World:
    w = World(topo, seed=4, start=8 * 3600.0)
    pop = Population(w, PopulationConfig(entities=entities, car_share=0.4, transit=False), None)
    pop.start()
    rng = random.Random(3)
    router = Router(w.net, TRAM, rng)
    for _ in range(3):  # two-part bodies on their rails (lateral 0)
        w.add("tram", router.trip(rng), s=20.0)
    for _ in range(int(seconds * 2)):
        w.step(0.5)
        pop.step()
    return w


def _same(w: World, ta) -> None:
    ids = sorted(w.agents)
    assert ta.ids.tolist() == ids
    for i, aid in enumerate(ids):
        a = w.agents[aid]
        assert (ta.x[i], ta.y[i]) == a.xy(), a  # exactly: the same operations in the same order
        assert ta.cells_of(i) == tuple(a.cells()), a


def test_the_arrays_hold_exactly_what_each_entity_says(helsinki):
    w = _world(helsinki)
    kinds = {a.name for a in w.agents.values()}
    assert {"car", "pedestrian", "tram"} <= kinds
    assert any(a.in_area_since is not None for a in w.agents.values())  # area walks, asked one by one
    ta = truth_arrays(w.agents, EdgeArrays(w.net))
    _same(w, ta)
    _same(w, truth_arrays(w.agents, None))  # no edge arrays: every entity asked
    by_table = truth_arrays(w.agents, EdgeArrays(w.net), w.routes)  # where along the routes: the world's table
    _same(w, by_table)
    assert by_table.x.tobytes() == ta.x.tobytes() and by_table.cells.tolist() == ta.cells.tolist()
    assert ta.rows(np.array([ta.ids[3], -5, ta.ids[-1] + 1000])).tolist() == [3, -1, -1]


def test_other_bodies_are_asked_for_their_own_truth(helsinki):
    class Body:
        def __init__(self, i):
            self.i = i

        def xy(self):
            return (float(self.i), -float(self.i))

        def cells(self):
            return (self.i, self.i + 1)

    w = World(helsinki)
    for table in (None, w.routes):
        ta = truth_arrays({5: Body(5), 2: Body(2)}, EdgeArrays(w.net), table)
        assert ta.ids.tolist() == [2, 5] and ta.x.tolist() == [2.0, 5.0] and ta.cells.tolist() == [2, 3, 5, 6]
    empty = truth_arrays({}, None)
    assert len(empty.ids) == 0 and empty.rows(np.array([1])).tolist() == [-1]


def test_edge_lookups_match_the_network_view_at_vertices_ends_and_beyond(helsinki):
    net = World(helsinki).net
    ea = EdgeArrays(net)
    rng = np.random.default_rng(2)
    e = rng.integers(0, net.n_edges, 20_000)
    length = np.array(net.edge_len)[e]
    off = rng.uniform(-0.2, 1.2, len(e)) * length
    off[:500] = 0.0
    off[500:1000] = length[500:1000]
    # exactly on inner vertices and cell breakpoints, where a search may land either side
    gi = rng.integers(0, len(net.gcum), 3000)
    ge = np.searchsorted(np.array(net.geom_off), gi, side="right") - 1
    bi = rng.integers(0, len(net.bp_start), 3000)
    be = np.searchsorted(np.array(net.bp_off), bi, side="right") - 1
    e = np.concatenate([e, ge, be])
    off = np.concatenate([off, np.array(net.gcum)[gi], np.array(net.bp_start)[bi]])
    x, y = ea.points(e, off)
    cells = ea.cells(e, off)
    for j in range(len(e)):
        assert (x[j], y[j]) == net.point(int(e[j]), float(off[j]))
        assert cells[j] == net.cell_at(int(e[j]), float(off[j]))
    with pytest.raises(IndexError):
        ea.points(np.array([net.n_edges + 5]), np.array([1.0]))
