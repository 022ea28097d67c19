"""`positions` gives every entity's `xy()` exactly, over arrays: walkers, cars in their lanes, area walkers."""

from __future__ import annotations

from sims.engine.population import Population, PopulationConfig
from sims.engine.positions import positions
from sims.engine.truth_arrays import EdgeArrays
from sims.engine.world import World
from tests.entitynet.client_fixtures import make_topology
from tests.sims.engine.test_routes import grid


def exact(w: World) -> None:
    bodies = list(w.agents.values())
    want = [a.xy() for a in bodies]
    for table in (None, w.routes):  # route lookups one by one, and over the world's route table
        got = positions(bodies, EdgeArrays(w.net), table)
        assert [tuple(p) for p in got.tolist()] == want


def test_positions_are_xy_on_a_grid_over_a_run():
    w = World(grid(), 3)
    pop = Population(w, PopulationConfig(50, 0.4, transit=False))
    pop.start()
    for _ in range(60):
        w.step(0.5)
        pop.step()
        exact(w)


def test_positions_on_the_city_map_with_area_walks(helsinki):
    w = World(helsinki, 2)
    pop = Population(w, PopulationConfig(300, 0.3, transit=False))
    pop.start()
    walking = 0
    for _ in range(120):
        w.step(0.5)
        pop.step()
        exact(w)
        walking += sum(a.in_area_since is not None for a in w.agents.values())
    assert walking > 0  # some were compared while inside their area walk


def test_ends_of_a_route_and_no_bodies():
    topo = make_topology({"A": (0.0, 0.0), "B": (50.0, 30.0)}, [("A", "B")])
    w = World(topo, 1)
    w.add("pedestrian", [(0, 1)], s=0.0, lateral=1.5)
    w.add("pedestrian", [(0, 1)], s=w.agents[1].route.length, lateral=-0.5)
    w.add("car", [(0, -1)], s=0.3)
    exact(w)
    assert positions([], EdgeArrays(w.net)).shape == (0, 2)


def test_the_route_table_drops_removed_routes_and_keeps_the_live_ones_exact():
    w = World(grid(), 5)
    w.routes.slack = 0
    pop = Population(w, PopulationConfig(40, 0.4, transit=False))
    pop.start()
    sizes = []
    for _ in range(320):
        w.step(0.5)
        pop.step()
        sizes.append(w.routes.size)
        exact(w)
    assert w.counters["arrived"] > 50  # more trips ended than there are live ones
    assert any(b < a for a, b in zip(sizes, sizes[1:], strict=False))  # compacted at least once
    assert w.routes.size <= 2 * w.routes.live + len(w.agents) * 10
