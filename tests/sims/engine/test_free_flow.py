"""The world's step over arrays (the free walkers, `sims.engine.free_flow`; the vehicles' leaders,
`sims.engine.leaders`) gives the scalar step's truth, bit for bit."""

from __future__ import annotations

import pytest

from sims.engine.population import Population, PopulationConfig
from sims.engine.world import World
from tests.entitynet.client_fixtures import make_topology
from tests.sims.engine.test_routes import grid


def state(w: World) -> list:
    """Everything of every live entity that the step writes, exactly (repr keeps the sign of a zero)."""
    return [repr((a.id, a.s, a.v, a.v0, a.distance, a.cause, a.blocker, a.blocked_since, a.in_area_since,
                  a.accept_until, a.next_stop, a.dwell_until, a._clock, sorted(a.held)))
            for a in w.agents.values()]


def twin_runs(topo, seconds: float, entities: int, dt: float = 0.5, seed: int = 4, cars: float = 0.4):
    """The same seeded world and population stepped vectorised and scalar, compared after every step."""
    worlds = [World(topo, seed, vectorised=v) for v in (True, False)]
    pops = [Population(w, PopulationConfig(entities, cars, transit=False)) for w in worlds]
    for p in pops:
        p.start()
    steps = 0
    for _ in range(int(seconds / dt)):
        for w, p in zip(worlds, pops, strict=True):
            w.step(dt)
            p.step()
        assert state(worlds[0]) == state(worlds[1])
        assert worlds[0].take_removed() == worlds[1].take_removed()
        steps += 1
    assert worlds[0].counters == worlds[1].counters
    return worlds[0], steps


def test_vectorised_and_scalar_worlds_agree_on_a_grid():
    w, _ = twin_runs(grid(), 120.0, 60)
    assert w.counters["arrived"] > 10  # trips ended (and were replaced) during the comparison
    assert len(w.free) > 0 and w.counters["spawned:car"] > 0


def test_dense_traffic_leaders_and_deadlocks_agree():
    """Cars only, packed on a small grid: queues, junction waits, accepted collisions, deletions."""
    w, _ = twin_runs(grid(), 200.0, 90, cars=1.0, seed=2)
    assert w.counters["avoided"] > 50 and w.counters["accepted"] + w.counters["deleted"] > 0


def test_vectorised_and_scalar_worlds_agree_on_the_city_map(helsinki):
    w, _ = twin_runs(helsinki, 30.0, 400)  # (all three counters are set by 17 s of this seeded run)
    assert w.counters["area_walks"] > 0 and w.counters["arrived"] > 0
    assert w.counters["avoided"] > 0  # cars followed one another in the scalar part meanwhile


@pytest.mark.parametrize("v, v0", [(0.0, 1.4), (1.4, 1.4), (2.9, 1.3), (-0.0, 1.4), (1.0, 0.0), (0.0, 0.0),
                                   (0.7, 1.3)])
def test_odd_speeds_step_the_same_way(v, v0):
    """Accelerating, too fast (braking), -0.0, a walker that wants to stand: scalar and array agree."""
    topo = make_topology({"A": (0.0, 0.0), "B": (500.0, 0.0)}, [("A", "B")])
    ws = [World(topo, 1, vectorised=vec) for vec in (True, False)]
    for w in ws:
        w.add("pedestrian", [(0, 1)], s=10.0, v=v, v0=v0)
    for _ in range(40):
        for w in ws:
            w.step(0.25)
        assert state(ws[0]) == state(ws[1])


def test_a_stalled_or_removed_walker_leaves_the_columns():
    topo = make_topology({"A": (0.0, 0.0), "B": (500.0, 0.0)}, [("A", "B")])
    w = World(topo, 1)
    a = w.add("pedestrian", [(0, 1)], s=10.0)
    b = w.add("pedestrian", [(0, 1)], s=20.0)
    c = w.add("pedestrian", [(0, 1)], s=490.0)
    assert len(w.free) == 3
    w.stall(a.id, 5.0)
    w.step(1.0)
    assert a.id not in w.free and a.s == 10.0 and a.v == 0.0
    w.remove(b.id, "deleted")
    assert len(w.free) == 1 and b.id not in w.agents
    for _ in range(20):
        w.step(1.0)
    assert c.id not in w.agents and len(w.free) == 0  # at the route's end: arrived, out of the columns
    assert a.s > 10.0  # the stall ended: it walks on in the scalar step
    assert w.take_removed() == [(b.id, "deleted"), (c.id, "arrived")]


def _street_with_stops(w: World) -> None:
    """Buses and a tram on timetables with stops, cars queued behind them, a bus that stands (v0 = 0), a stall,
    a stop-serving pedestrian and walkers on one long street."""
    from sims.engine.agents import Stop

    t0 = w.now
    w.add("bus", [(0, 1)], s=0.0, v=0.0, stops=[Stop(80.0, 6.0, "a", 15.0), Stop(260.0, 4.0, "b", 40.0)],
          timetable=t0)
    w.add("tram", [(0, 1)], s=5.0, v=7.3, stops=[Stop(150.0, 8.0, "c", 20.0), Stop(420.0, 5.0, "d", 60.0)],
          timetable=t0)
    w.add("bus", [(0, 1)], s=30.0, v=3.1, stops=[Stop(120.0, 10.0, "e"), Stop(300.0, 3.0, "f")])
    for k in range(6):
        w.add("car", [(0, 1)], s=40.0 + 12.0 * k, v=float(k) * 1.7)
    w.add("car", [(0, -1)], s=10.0, v=13.9)  # oncoming
    w.add("bus", [(0, 1)], s=200.0, v=4.0, v0=0.0)  # wants to stand: brakes at decel
    w.add("pedestrian", [(0, 1)], s=3.0, stops=[Stop(50.0, 5.0, "p")])
    for k in range(5):
        w.add("pedestrian", [(0, 1)], s=20.0 * k)


def test_vehicles_with_stops_timetables_and_stalls_agree():
    """The vehicles' IDM over arrays (`sims.engine.idm_arrays`): timetabled stops served, dwells, queues behind
    a standing bus, a stall, entering vehicles: the same truth as the scalar step after every step."""
    topo = make_topology({"A": (0.0, 0.0), "B": (600.0, 0.0)}, [("A", "B")])
    ws = [World(topo, 3, start=8 * 3600.0, vectorised=vec) for vec in (True, False)]
    for w in ws:
        _street_with_stops(w)
    for i in range(240):
        for w in ws:
            if i == 30:
                w.stall(5, 12.0)
            if i == 90:
                w.add("car", [(0, 1)], s=0.0, v=11.0)
            w.step(0.25 if i % 3 else 0.5)
        assert state(ws[0]) == state(ws[1])
        assert ws[0].stop_lateness == ws[1].stop_lateness
    assert ws[0].counters == ws[1].counters
    assert ws[0].counters["stops_served"] >= 4 and ws[0].counters["avoided"] > 0
