"""GTFS-realtime feeds (gtfs-realtime-bindings): the replay producer's VehiclePositions and TripUpdates, and
the proxy's reader of any producer's.

Reading turns a FeedMessage into plain records: `Position` (a fix: vehicle, trip, lon/lat, time, optional
speed and bearing) and the same `Call` records SIRI gives (one per StopTimeUpdate with an arrival time), so
trip updates drive exactly the ETA motion SIRI does. Truncated or garbage protobuf raises `FeedError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from google.protobuf.message import DecodeError
from google.transit import gtfs_realtime_pb2 as rt

from proxies.replay_core import Run, Visit
from proxies.siri_xml import Call, ServiceClock

MAX_FEED_BYTES = 64 << 20


class FeedError(ValueError):
    """A GTFS-realtime answer that cannot be used."""


@dataclass(frozen=True)
class Position:
    """A GTFS-rt VehiclePosition as a plain record: the proxy feeds it to the vehicle's client core as
    a phone's fix."""
    vehicle: str
    trip_id: str
    route_id: str
    direction: str
    lon: float
    lat: float
    t: float  # POSIX seconds of the fix
    speed: float | None  # m/s
    bearing: float | None  # degrees clockwise from north


def _header(feed: rt.FeedMessage, stamp: float) -> None:
    feed.header.gtfs_realtime_version = "2.0"
    feed.header.incrementality = rt.FeedHeader.FULL_DATASET
    feed.header.timestamp = int(stamp)


def build_vehicle_positions(states: list[tuple[Run, float, float, int, bool]], now: float,
                            clock: ServiceClock, speeds: dict[str, tuple[float, float]] | None = None) -> bytes:
    """VehiclePositions of the traced vehicles (`ReplayWorld.vehicle_states`)."""
    feed = rt.FeedMessage()
    stamp = clock.epoch(now)
    _header(feed, stamp)
    for run, lon, lat, k, at in states:
        ent = feed.entity.add()
        ent.id = run.vehicle
        vp = ent.vehicle
        vp.trip.trip_id = run.dep.journey
        vp.trip.route_id = run.dep.pattern.route_id
        if run.dep.pattern.direction.isdigit():
            vp.trip.direction_id = int(run.dep.pattern.direction)
        vp.vehicle.id = run.vehicle
        vp.position.longitude = lon
        vp.position.latitude = lat
        if speeds and run.vehicle in speeds:
            vp.position.speed, vp.position.bearing = speeds[run.vehicle]
        vp.current_stop_sequence = k + 1
        vp.stop_id = run.dep.pattern.stop_ids[k]
        vp.current_status = (rt.VehiclePosition.STOPPED_AT if at else rt.VehiclePosition.IN_TRANSIT_TO)
        vp.timestamp = int(stamp)
    return feed.SerializeToString()


def build_trip_updates(visits: list[Visit], now: float, clock: ServiceClock) -> bytes:
    """TripUpdates: one entity per traced journey, a StopTimeUpdate per visit (arrival time, the ETA)."""
    feed = rt.FeedMessage()
    _header(feed, clock.epoch(now))
    by_journey: dict[str, list[Visit]] = {}
    for v in visits:
        if v.vehicle:
            by_journey.setdefault(v.journey, []).append(v)
    for journey, vs in by_journey.items():
        ent = feed.entity.add()
        ent.id = journey
        tu = ent.trip_update
        tu.trip.trip_id = journey
        tu.trip.route_id = vs[0].line
        if vs[0].direction.isdigit():
            tu.trip.direction_id = int(vs[0].direction)
        tu.vehicle.id = vs[0].vehicle
        for v in sorted(vs, key=lambda v: v.order):
            stu = tu.stop_time_update.add()
            stu.stop_sequence = v.order
            stu.stop_id = v.stop_id
            stu.arrival.time = int(clock.epoch(v.expected_arrival))
            stu.departure.time = int(clock.epoch(v.expected_departure))
        tu.timestamp = int(clock.epoch(now))
    return feed.SerializeToString()


def _parse(data: bytes) -> rt.FeedMessage:
    if len(data) > MAX_FEED_BYTES:
        raise FeedError(f"feed of {len(data)} bytes is larger than the {MAX_FEED_BYTES} allowed")
    if not data:
        raise FeedError("empty feed")
    feed = rt.FeedMessage()
    try:
        feed.ParseFromString(data)
    except (DecodeError, ValueError, RuntimeError) as exc:
        raise FeedError(f"malformed GTFS-realtime protobuf: {exc}") from None
    if not feed.IsInitialized() or not feed.header.gtfs_realtime_version:
        raise FeedError("not a GTFS-realtime FeedMessage (no header)")
    return feed


def parse_vehicle_positions(data: bytes) -> tuple[float, list[Position]]:
    """(feed timestamp, positions) of a VehiclePositions feed; entities without a position are skipped."""
    feed = _parse(data)
    stamp = float(feed.header.timestamp)
    out = []
    for ent in feed.entity:
        if not ent.HasField("vehicle") or not ent.vehicle.HasField("position"):
            continue
        vp = ent.vehicle
        lon, lat = vp.position.longitude, vp.position.latitude
        if not (math.isfinite(lon) and math.isfinite(lat) and -180 <= lon <= 180 and -90 <= lat <= 90):
            continue
        t = float(vp.timestamp) if vp.timestamp else stamp
        speed = vp.position.speed if vp.position.HasField("speed") else None
        bearing = vp.position.bearing if vp.position.HasField("bearing") else None
        out.append(Position(vp.vehicle.id or ent.id, vp.trip.trip_id, vp.trip.route_id,
                            str(vp.trip.direction_id) if vp.trip.HasField("direction_id") else "",
                            lon, lat, t, speed, bearing))
    return stamp, out


def parse_trip_updates(data: bytes) -> tuple[float, list[Call]]:
    """(feed timestamp, calls) of a TripUpdates feed, one Call per StopTimeUpdate with an arrival time."""
    feed = _parse(data)
    stamp = float(feed.header.timestamp)
    out = []
    for ent in feed.entity:
        if not ent.HasField("trip_update"):
            continue
        tu = ent.trip_update
        vehicle = tu.vehicle.id
        direction = str(tu.trip.direction_id) if tu.trip.HasField("direction_id") else ""
        for stu in tu.stop_time_update:
            arr = stu.arrival.time if stu.HasField("arrival") and stu.arrival.time else None
            dep = stu.departure.time if stu.HasField("departure") and stu.departure.time else None
            if arr is None and dep is None:
                continue
            out.append(Call(stu.stop_id, vehicle, tu.trip.route_id, direction, tu.trip.trip_id,
                            stu.stop_sequence or None, float(arr or dep), float(dep or arr), None, False,
                            bool(vehicle), None, None))
    return stamp, out
