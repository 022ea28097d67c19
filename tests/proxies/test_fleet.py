"""The proxy core (sans-IO) on the synthetic line: what is kept and what discarded, clocks, vehicles as honest
clients, and leaving."""

from __future__ import annotations

import pytest

from entitynet.protocol import Publish, Unpublish
from proxies.fleet import Fleet
from proxies.replay_core import ReplayWorld
from proxies.sim import run_sim
from proxies.siri_xml import Call

T0 = 1_645_510_000.0


def _call(stop: int, eta: float, *, vehicle="V1", journey="T_east:28800", order=None, monitored=True, at=False):
    return Call(f"S{stop}", vehicle, "1001", "0", journey, stop + 1 if order is None else order, eta, eta + 20.0,
                None, at, monitored, None, None)


def test_only_traced_vehicles_on_the_map_routes_are_kept(line_topo, line_book):
    fleet = Fleet(line_topo, line_book)
    calls = [_call(2, T0 + 60.0), _call(3, T0 + 150.0), _call(2, T0 + 90.0, vehicle="", monitored=False),
             _call(2, T0 + 30.0, vehicle="X", journey="unknown-trip")]
    fleet.ingest(calls, T0, T0)
    assert set(fleet.vehicles) == {"V1"}
    c = fleet.counters
    assert (c.calls, c.used, c.untraced, c.off_map) == (4, 1, 1, 1)
    assert c.discarded_fraction == pytest.approx(0.75)
    veh = fleet.vehicles["V1"]
    assert line_book.routes["T east"].stops[1].s < veh.motion.s < line_book.routes["T east"].stops[2].s


def test_latency_does_not_shift_the_etas(line_topo, line_book):
    """The clock offset is the smallest (received - ResponseTimestamp) of the recent answers."""
    fleet = Fleet(line_topo, line_book, granularity=0.0)
    fleet.ingest([_call(2, T0 + 60.0)], T0, T0 + 0.2)  # a quick answer
    fleet.ingest([_call(2, T0 + 60.0)], T0 + 20.0, T0 + 28.0)  # 8 s late
    assert fleet.vehicles["V1"].motion.eta[2] == pytest.approx(T0 + 60.2)


def test_vehicles_publish_as_honest_clients_and_leave_when_stale(line_topo, line_book):
    fleet = Fleet(line_topo, line_book, stale_after=30.0)
    fleet.ingest([_call(2, T0 + 60.0), _call(3, T0 + 150.0)], T0, T0)
    msgs = fleet.tick(T0)
    assert len(msgs) == 1 and isinstance(msgs[0], Publish) and msgs[0].cells
    pubs = [m for t in range(1, 25) for m in fleet.tick(T0 + t)]
    assert all(isinstance(m, Publish) for m in pubs)
    assert fleet.vehicles["V1"].motion.s > 0
    out = fleet.tick(T0 + 31.0)
    assert out and isinstance(out[-1], Unpublish) and not fleet.vehicles
    assert fleet.counters.retired_stale == 1


def test_a_vehicle_on_its_next_trip_leaves_and_comes_back_on_the_new_route(line_topo, line_book):
    fleet = Fleet(line_topo, line_book)
    fleet.ingest([_call(2, T0 + 60.0)], T0, T0)
    fleet.tick(T0)
    old = fleet.vehicles["V1"].entity
    fleet.ingest([_call(3, T0 + 70.0, journey="T_west:29000", order=3)], T0 + 20.0, T0 + 20.0)
    out = fleet.tick(T0 + 20.0)
    assert Unpublish(old) in out
    assert fleet.vehicles["V1"].trip == "T west" and fleet.vehicles["V1"].entity != old


def test_a_two_minute_outage_loses_no_vehicle(line_topo, line_book):
    world = ReplayWorld(line_book.schedule, granularity=60.0)
    res, fleet = run_sim(line_topo, line_book, world, start=8 * 3600.0, duration=420.0, poll=20.0,
                         outage=(120.0, 240.0), warmup=30.0)
    from proxies.bench import recovery

    assert res.lost == 0 and len(res.seen) >= 3
    back = recovery(res.series, (120.0, 240.0), 30.0)
    assert back is not None and back <= 60.0  # the error is back to its usual within a minute of the outage


def test_the_stop_id_decides_not_a_stop_sequence_that_counts_otherwise(line_topo, line_book):
    """Real feeds number stop_sequence their own way (gaps, or HSL's trimmed trips starting at 19): S3 is S3
    even when its stop_sequence (2) would be another stop's index + 1."""
    fleet = Fleet(line_topo, line_book, granularity=0.0)
    fleet.ingest([_call(3, T0 + 60.0, order=2), _call(4, T0 + 150.0, order=3)], T0, T0)
    assert set(fleet.vehicles["V1"].motion.eta) == {3, 4}


def test_stops_served_and_vehicles_by_mode_count_the_vehicles_that_left_too(line_topo, line_book):
    fleet = Fleet(line_topo, line_book, stale_after=400.0, granularity=0.0)
    fleet.ingest([_call(2, T0 + 60.0), _call(3, T0 + 150.0), _call(4, T0 + 240.0)], T0, T0)
    assert fleet.by_mode() == {"tram": 1} and fleet.stops_served() == 0
    for t in range(0, 200):
        fleet.tick(T0 + t)
    served = fleet.stops_served()
    assert served >= 1  # stood at stop 2 (and 3) on its ETAs
    fleet.tick(T0 + 1000.0)  # stale: it leaves, its stops stay counted
    assert not fleet.vehicles and fleet.by_mode() == {}
    assert fleet.stops_served() == served


def test_a_position_the_client_core_refuses_is_counted_and_nothing_else_changes(line_topo, line_book):
    """A GTFS-rt position that is not a fix (NaN) is refused by the vehicle's client core: counted in
    `fixes_rejected`, not in `fixes`, and the vehicle goes on from its motion as before."""
    fleet = Fleet(line_topo, line_book)
    fleet.ingest([_call(2, T0 + 60.0), _call(3, T0 + 150.0)], T0, T0)
    fleet.tick(T0)
    before = fleet.counters.fixes
    fleet.fix("V1", float("nan"), 0.0, T0 + 0.5)
    assert (fleet.counters.fixes_rejected, fleet.counters.fixes) == (1, before)
    assert fleet.vehicles["V1"].last_fix < T0 + 0.5
    assert all(isinstance(m, Publish) for t in range(1, 5) for m in fleet.tick(T0 + t))
