"""The engine's behaviours and collision rules on tiny networks (a T, an X, a single track), deterministically."""

from __future__ import annotations

import math

import pytest

from sims.engine.agents import Stop
from sims.engine.behaviour import idm
from sims.engine.crossings import Crossings, Movement, boxes_overlap
from sims.engine.world import World
from tests.entitynet.client_fixtures import cross, make_topology, tee
from topology.raw import PEDESTRIAN, TRAM


def run(w: World, seconds: float, dt: float = 0.1) -> None:
    for _ in range(int(round(seconds / dt))):
        w.step(dt)


def test_idm_is_defined_everywhere():
    assert idm(10.0, 10.0, 1.5, 2.5, 1.5, 2.0) == pytest.approx(0.0)
    assert idm(0.0, 10.0, 1.5, 2.5, 1.5, 2.0) == pytest.approx(1.5)
    assert idm(5.0, 10.0, 1.5, 2.5, 1.5, 2.0, gap=0.0) < -5
    assert idm(5.0, 0.0, 1.5, 2.5, 1.5, 2.0) == -2.5
    assert math.isfinite(idm(5.0, 10.0, 1.5, 2.5, 1.5, 2.0, gap=1e-9, dv=-30))


def test_car_follows_a_stalled_leader_without_touching_it():
    topo = make_topology({"A": (0.0, 0.0), "B": (600.0, 0.0)}, [("A", "B")])
    w = World(topo, seed=1)
    lead = w.add("car", [(0, 1)], s=200.0, v=0.0, v0=10.0)
    w.stall(lead.id, 1000.0)
    car = w.add("car", [(0, 1)], s=50.0, v=10.0, v0=10.0)
    run(w, 40.0)
    gap = (lead.s - lead.length) - car.s
    assert car.v == pytest.approx(0.0, abs=0.05)
    assert 0.3 <= gap <= car.params.gap + 1.0
    assert w.counters["avoided"] == 1


def test_x_junction_first_to_arrive_passes_first():
    w = World(cross(arm=100.0, junction_radius=10.0), seed=1)
    late = w.add("car", [(0, 1), (1, 1)], s=40.0, v=10.0, v0=10.0)  # W -> E, one metre behind
    first = w.add("car", [(2, 1), (3, 1)], s=41.0, v=10.0, v0=10.0)  # S -> N
    run(w, 3.0)
    assert late.cause == "crossing" and first.cause == ""
    t_first = t_late = None
    for _ in range(300):
        w.step(0.1)
        if t_first is None and first.s > 100.0:
            t_first = w.now
        if t_late is None and late.s > 100.0:
            t_late = w.now
    assert t_first is not None and t_late is not None and t_first < t_late
    # the late one entered only after the first one's body had left the junction zone
    assert t_late - t_first > 1.0
    assert w.counters["avoided"] >= 1


def test_x_junction_opposite_straight_lanes_pass_together():
    w = World(cross(arm=100.0, junction_radius=10.0), seed=1)
    east = w.add("car", [(0, 1), (1, 1)], s=40.0, v=10.0, v0=10.0)  # W -> E
    west = w.add("car", [(1, -1), (0, -1)], s=40.0, v=10.0, v0=10.0)  # E -> W, own lane 6 m away
    run(w, 8.0)
    assert w.counters["avoided"] == 0
    assert east.s > 110 and west.s > 110


def test_t_junction_turning_car_waits_for_the_earlier_straight_one():
    w = World(tee(arm=100.0, junction_radius=10.0), seed=1)
    straight = w.add("car", [(0, 1), (1, 1)], s=45.0, v=10.0, v0=10.0)  # W -> E
    turner = w.add("car", [(2, -1), (1, 1)], s=40.0, v=10.0, v0=10.0)  # S -> C -> E (merges)
    run(w, 2.0)
    assert turner.cause == "crossing"
    run(w, 20.0)
    # both reach E, the turner behind the straight one, never overlapping it
    assert straight.id not in w.agents or turner.id not in w.agents or straight.s - straight.length > turner.s


def test_single_track_head_on_deadlock_accepts_one_collision():
    topo = make_topology({"A": (0.0, 0.0), "B": (400.0, 0.0)}, [("A", "B", TRAM)])
    w = World(topo, seed=1)
    east = w.add("tram", [(0, 1)], s=150.0, v=5.0)
    west = w.add("tram", [(0, -1)], s=150.0, v=5.0)
    run(w, 30.0)
    assert east.v == 0.0 and west.v == 0.0 and w.counters["accepted"] == 0
    run(w, 60.0)
    assert w.counters["accepted"] == 1  # one side accepts, the other waits for it to pass
    run(w, 60.0)
    assert not w.agents and w.counters["arrived"] == 2 and w.counters["deleted"] == 0


def test_blocked_at_a_junction_too_long_is_deleted():
    w = World(cross(arm=100.0, junction_radius=10.0), seed=1)
    stuck = w.add("car", [(2, 1), (3, 1)], s=95.0, v=0.0, v0=10.0)  # in the junction, S -> N
    run(w, 0.2)
    w.stall(stuck.id, 10_000.0)
    waiting = w.add("car", [(0, 1), (1, 1)], s=60.0, v=8.0, v0=10.0)  # W -> E must cross its path
    run(w, waiting.params.delete_after - 10.0)
    assert waiting.id in w.agents and waiting.cause == "crossing"
    run(w, 20.0)
    assert waiting.id not in w.agents and w.counters["deleted"] == 1 and w.counters["accepted"] == 0


def test_bus_stops_and_dwells_then_leaves_at_the_route_end():
    topo = make_topology({"A": (0.0, 0.0), "B": (400.0, 0.0)}, [("A", "B")])
    w = World(topo, seed=1)
    bus = w.add("bus", [(0, 1)], s=20.0, v=0.0, stops=[Stop(100.0, 20.0, "x"), Stop(300.0, 10.0, "y")])
    at_stop = []
    for _ in range(1200):
        w.step(0.1)
        if bus.id in w.agents and abs(bus.s - 100.0) < 0.01 and bus.v == 0.0:
            at_stop.append(w.now)
    assert at_stop and 19.5 <= at_stop[-1] - at_stop[0] <= 20.5
    assert w.counters["stops_served"] == 2 and w.counters["arrived"] == 1


def test_tram_has_two_parts_on_the_rails():
    nodes = {"A": (0.0, 0.0), "B": (100.0, 0.0), "C": (100.0, 100.0)}
    topo = make_topology(nodes, [("A", "B", TRAM), ("B", "C", TRAM)])
    w = World(topo, seed=1)
    tram = w.add("tram", [(0, 1), (1, 1)], s=110.0, v=0.0)
    front, joint, aft = tram.part_points()
    assert front == pytest.approx((100.0, 10.0))
    assert joint == pytest.approx((96.2, 0.0), abs=1e-6)  # 13.8 m behind along the rails, round the corner
    assert aft == pytest.approx((82.4, 0.0), abs=1e-6)
    assert len(tram.cells()) >= 1


def test_pedestrians_spread_across_the_walkway_and_ignore_vehicles():
    topo = make_topology({"A": (0.0, 0.0), "B": (300.0, 0.0)}, [("A", "B", PEDESTRIAN | 2)])
    w = World(topo, seed=3)
    peds = [w.add("pedestrian", [(0, 1)], s=10.0) for _ in range(40)]
    lats = [p.lateral for p in peds]
    assert max(lats) > 1.5 and min(lats) < -1.5 and max(abs(x) for x in lats) <= 2.5
    run(w, 10.0)
    assert all(p.s > 15.0 for p in peds) and w.counters["avoided"] == 0


def test_same_seed_same_run():
    def once():
        w = World(cross(arm=100.0), seed=5)
        for k in range(6):
            w.add("car", [(0, 1), (1, 1)] if k % 2 else [(2, 1), (3, 1)], s=10.0 * k)
            w.add("pedestrian", [(3, -1), (2, -1)], s=5.0 * k)
        run(w, 30.0)
        return [(a.id, round(a.s, 9), round(a.v, 9)) for a in w.agents.values()], dict(w.counters)
    assert once() == once()


def test_bad_input_is_refused_clearly():
    w = World(cross(), seed=1)
    with pytest.raises(ValueError, match="not connected"):
        w.add("car", [(0, 1), (2, 1)])
    with pytest.raises(ValueError, match="no entity type 'boat'"):
        w.add("boat", [(0, 1)])
    with pytest.raises(ValueError, match="not on the route"):
        w.add("car", [(0, 1)], s=500.0)
    with pytest.raises(ValueError, match="forward"):
        w.step(0.0)


def test_crossing_reservations_first_come_on_boxes():
    c = Crossings()
    ew = Movement((0, 1), (1, 1), (-10, -4, 10, -2))
    sn = Movement((2, 1), (3, 1), (2, -10, 4, 10))
    we = Movement((1, -1), (0, -1), (-10, 2, 10, 4))
    assert boxes_overlap(ew.box, sn.box) and not boxes_overlap(ew.box, we.box)
    assert c.request(9, 1, ew, 0.0)
    assert c.request(9, 3, we, 0.2)  # no conflict with the holder: passes alongside
    assert not c.request(9, 2, sn, 0.5)  # crosses both holders' boxes
    c.release(9, 1)
    assert not c.request(9, 2, sn, 3.0)  # still crosses the opposite lane's holder
    late = Movement((5, 1), (3, 1), (2, -10, 4, 10))
    c.release(9, 3)
    assert not c.request(9, 4, late, 1.0)  # asked after 2 (0.5 s): must wait for it
    assert c.request(9, 2, sn, 4.0)
    assert not c.request(9, 4, late, 4.0)
    assert c.holders(9) == [2]


def test_pedestrian_walks_inside_the_area_at_the_end_of_its_trip():
    from sims.mobility.areas import point_in_ring
    from tests.entitynet.client_fixtures import area_square

    topo = area_square(side=60.0)  # edge 0: W -> Q (the square's node)
    w = World(topo, seed=2)
    ped = w.add("pedestrian", [(0, 1)], s=120.0, area_walk=60.0)
    ring = topo.area_polygons.exterior(0)
    run(w, 20.0)
    assert ped.in_area_since is not None and w.counters["area_walks"] == 1
    seen = set()
    for _ in range(40):
        run(w, 1.0)
        if ped.id not in w.agents:
            break
        x, y = ped.xy()
        assert point_in_ring(ring, x, y)
        assert ped.cells() == (int(topo.area_cell[0]),)
        seen.add((round(x), round(y)))
    assert len(seen) > 3  # it moves about inside
    run(w, 120.0)
    assert ped.id not in w.agents and w.counters["arrived"] == 1
