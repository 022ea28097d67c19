"""Buses and trams keep their timetable: the speed between stops is the one the stop times imply (issue 11).

Deterministic, on a straight 1.2 km street: an unobstructed bus reaches each stop at its scheduled time within
two ticks (never faster than its type's maximum), a bus held up behind a broken-down car is late and moves
only as fast as it may (no jump to catch up), a time that cannot be made is driven at the maximum, the
schedule reader keeps each stop's arrival, and a vehicle spawned mid-run is placed where its timetable puts it.
"""

from __future__ import annotations

import pytest

from sims.engine.agents import Stop
from sims.engine.behaviour import APPROACH_BRAKING, TIMETABLE_VMIN, timetable_speed
from sims.engine.population import timetable_position
from sims.engine.schedule import read_schedule
from sims.engine.world import World
from tests.entitynet.client_fixtures import make_topology
from tests.sims.engine.test_schedule import line_map, write_feed
from topology.gtfs import parse_time
from topology.raw import TRAM

DT = 0.5  # the simulation's default tick (2 Hz)
T0 = 8 * 3600.0


def street():
    return make_topology({"A": (0.0, 0.0), "B": (1200.0, 0.0)}, [("A", "B")])


def drive(w: World, agent, until: float) -> list[tuple[float, float, float]]:
    """Step the world to `until` (or until the agent leaves); (time, s, v) of the agent after each tick."""
    track = []
    while agent.id in w.agents and w.now < until - 1e-9:
        w.step(DT)
        track.append((w.now, agent.s, agent.v))
    return track


def test_an_unobstructed_bus_reaches_each_stop_on_time():
    w = World(street(), seed=1, start=T0)
    stops = [Stop(200.0, 20.0, "a", 35.0), Stop(500.0, 15.0, "b", 100.0), Stop(1000.0, 10.0, "c", 190.0)]
    bus = w.add("bus", [(0, 1)], s=0.0, v=0.0, stops=stops, timetable=T0)
    track = drive(w, bus, T0 + 400.0)
    assert w.counters["stops_served"] == 3
    assert w.stop_lateness == pytest.approx([0.0, 0.0, 0.0], abs=2 * DT)
    assert max(v for _t, _s, v in track) <= bus.params.vmax + 1e-9
    # the first leg (200 m in 35 s) is driven well below the bus's own speed: the timetable sets it
    first_leg = [v for t, _s, v in track if t < T0 + 30.0]
    assert max(first_leg) < 0.75 * bus.params.vmax


def test_an_unobstructed_tram_reaches_each_stop_on_time():
    topo = make_topology({"A": (0.0, 0.0), "B": (1200.0, 0.0)}, [("A", "B", TRAM)])
    w = World(topo, seed=1, start=T0)
    stops = [Stop(300.0, 10.0, "a", 40.0), Stop(700.0, 10.0, "b", 100.0), Stop(1100.0, 10.0, "c", 160.0)]
    tram = w.add("tram", [(0, 1)], s=0.0, v=9.0, stops=stops, timetable=T0)  # enters the map under way
    drive(w, tram, T0 + 400.0)
    assert w.stop_lateness == pytest.approx([0.0, 0.0, 0.0], abs=2 * DT)


def test_a_blocked_bus_is_late_and_does_not_jump():
    w = World(street(), seed=1, start=T0)
    car = w.add("car", [(0, 1)], s=300.0, v=0.0, v0=10.0)
    w.stall(car.id, 60.0)  # a breakdown in the bus's lane for 60 s, then it drives off
    bus = w.add("bus", [(0, 1)], s=0.0, v=0.0, stops=[Stop(600.0, 10.0, "a", 70.0)], timetable=T0)
    track = drive(w, bus, T0 + 300.0)
    assert w.counters["stops_served"] == 1 and w.counters["avoided"] >= 1
    (late,) = w.stop_lateness
    # it stood behind the car until 60 s at least 300 m short of the stop: no earlier than that at its maximum
    assert late >= 60.0 + 300.0 / bus.params.vmax - 70.0 - DT
    steps = [(s1 - s0) for (_t0, s0, _v0), (_t1, s1, _v1) in zip(track, track[1:], strict=False)]
    assert max(steps) <= bus.params.vmax * DT + 1e-6  # caught up by driving, never by a jump
    assert max(v for _t, _s, v in track) <= bus.params.vmax + 1e-9


def test_a_time_that_cannot_be_made_is_driven_at_the_maximum():
    w = World(street(), seed=1, start=T0)
    bus = w.add("bus", [(0, 1)], s=0.0, v=0.0, stops=[Stop(900.0, 10.0, "a", 30.0)], timetable=T0)
    track = drive(w, bus, T0 + 200.0)
    assert max(v for _t, _s, v in track) == pytest.approx(bus.params.vmax, rel=0.02)
    assert w.stop_lateness[0] > 30.0


def test_timetable_speed_is_defined_everywhere():
    assert timetable_speed(100.0, 0.0, 5.0, 1.2, 1.5, 13.0) == 13.0  # due now or past: as fast as allowed
    assert timetable_speed(100.0, -5.0, 5.0, 1.2, 1.5, 13.0) == 13.0
    assert timetable_speed(1000.0, 10.0, 0.0, 1.2, 1.5, 13.0) == 13.0  # cannot be made
    assert timetable_speed(0.0, 10.0, 0.0, 1.2, 1.5, 13.0) == TIMETABLE_VMIN  # there already
    assert timetable_speed(10.0, 1e6, 0.0, 1.2, 1.5, 13.0) == TIMETABLE_VMIN  # far ahead of time: crawl on
    c = timetable_speed(300.0, 40.0, 0.0, 1.2, 1.5, 13.0)  # accelerate to c, cruise, brake: 40 s in all
    b = 1.5 * APPROACH_BRAKING
    assert c / 1.2 + (300.0 - c * c / 2.4 - c * c / (2 * b)) / c + c / b == pytest.approx(40.0)


def test_the_schedule_keeps_each_stops_arrival(tmp_path):
    sched = read_schedule(write_feed(tmp_path / "f.zip"), line_map(), date="20220222")
    tram = next(d for d in sched.departures if d.trip_id == "t1")
    assert [d.time + st.arrive for st, d in zip(tram.stops, [tram, tram], strict=True)] == pytest.approx(
        [parse_time("08:01:30"), parse_time("08:02:30")])


def test_a_vehicle_under_way_is_placed_by_its_timetable():
    stops = [Stop(200.0, 20.0, "a", 40.0), Stop(500.0, 10.0, "b", 100.0)]
    assert timetable_position(stops, 20.0, 9.0) == (pytest.approx(100.0), False)  # half way to the first stop
    assert timetable_position(stops, 50.0, 9.0) == (200.0, True)  # dwelling there
    assert timetable_position(stops, 80.0, 9.0) == (pytest.approx(350.0), False)  # half way to the next
    assert timetable_position(stops, 120.0, 9.0) == (pytest.approx(590.0), False)  # on at cruise after the last


def test_the_cached_schedule_keeps_the_timetable(tmp_path):
    from sims.engine.schedule import load_schedule

    feed, topo = write_feed(tmp_path / "f.zip"), line_map()
    fresh = load_schedule(feed, topo, date="20220222", cache=tmp_path / "cache")
    cached = load_schedule(feed, topo, date="20220222", cache=tmp_path / "cache")  # read back from the JSON
    assert list(tmp_path.joinpath("cache").glob("schedule-*.json"))
    assert [st.arrive for d in cached.departures for st in d.stops] == \
        [st.arrive for d in fresh.departures for st in d.stops]
    assert all(st.arrive is not None for d in cached.departures for st in d.stops)


def test_the_report_summarises_schedule_adherence():
    from sims.engine.sim import timetable_summary

    assert timetable_summary([])["stops"] == 0 and timetable_summary([])["lateness_p50_s"] is None
    s = timetable_summary([0.0, 1.0, 2.0, 100.0])
    assert s["stops"] == 4 and s["lateness_p50_s"] == 1.5 and s["lateness_max_s"] == 100.0
    assert s["late_over_60s"] == 0.25
