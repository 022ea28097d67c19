"""A GTFS schedule as the replay producer and the proxies need it: each trip's stop times and its shape with
the distance of every stop along it, and the departures (frequencies expanded).

The feed is read, its service day chosen and its frequencies expanded by the project's one GTFS reader and
schedule model (`topology.gtfs`, `topology.schedule`); what this adapter adds is the proxies' own view: shapes
in the feed's coordinates (WGS84) with distances in metres from a local equirectangular projection around the
feed's centre (exact to well under 0.1 % across a city, and cheap), each stop's distance along its trip's
shape, and journey references the SIRI and GTFS-rt codes can carry (`nmtoken`). A trip without a shape runs on
the shape made of its stops, the same one `topology.gtfs.match_shapes` matches onto the map.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path as FsPath

import numpy as np

from topology.gtfs import Feed, GtfsError, read_feed
from topology.schedule import build_timetable

EARTH_R = 6_371_008.8


class ScheduleError(GtfsError):
    """A feed that cannot be used (unreadable, missing files, no trips in the area)."""


@dataclass
class Pattern:
    """One template trip: its stops, times relative to its first departure, and its shape."""

    trip_id: str
    route_id: str
    direction: str
    shape_id: str
    stop_ids: list[str]
    arr: np.ndarray  # seconds from the first departure
    dep: np.ndarray
    stop_dist: np.ndarray = field(default_factory=lambda: np.zeros(0))  # metres along the shape


@dataclass(frozen=True)
class Departure:
    """One run of a pattern: `start` is the service-day second of its first departure."""

    journey: str  # unique: nmtoken(trip id), and ":" + start for a frequency-expanded run
    pattern: Pattern
    start: int


@dataclass
class Schedule:
    """The GTFS feed reduced to what the proxy and the replay need, in local metres around
    (lon0, lat0) so that distances along shapes are plain arithmetic."""
    routes: dict[str, tuple[str, str]]  # route_id -> (mode, short name)
    stops: dict[str, tuple[str, float, float]]  # stop_id -> (name, lon, lat)
    shapes: dict[str, np.ndarray]  # shape_id -> (n, 2) local metres
    shape_cum: dict[str, np.ndarray]  # shape_id -> cumulative length
    departures: list[Departure]
    lon0: float
    lat0: float
    service_date: str  # YYYYMMDD of the service day (topology.schedule.service_day), "" without a calendar

    def to_xy(self, lon, lat) -> np.ndarray:
        """Local metres of lon/lat (arrays allowed), by the equirectangular approximation: exact enough
        over a city, and the inverse of `to_lonlat`."""
        k = math.cos(math.radians(self.lat0))
        lon, lat = np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
        return np.stack([np.radians(lon - self.lon0) * EARTH_R * k, np.radians(lat - self.lat0) * EARTH_R], axis=-1)

    def to_lonlat(self, x: float, y: float) -> tuple[float, float]:
        """Lon/lat of a local point: what the replay reports as a VehicleLocation."""
        k = math.cos(math.radians(self.lat0))
        return self.lon0 + math.degrees(x / (EARTH_R * k)), self.lat0 + math.degrees(y / EARTH_R)

    def point_on_shape(self, shape_id: str, d: float) -> tuple[float, float]:
        """The local (x, y) `d` metres along a shape (clamped to it)."""
        xy, cum = self.shapes[shape_id], self.shape_cum[shape_id]
        if d <= 0.0:
            return float(xy[0, 0]), float(xy[0, 1])
        if d >= cum[-1]:
            return float(xy[-1, 0]), float(xy[-1, 1])
        k = int(np.searchsorted(cum, d, side="right")) - 1
        seg = cum[k + 1] - cum[k]
        f = (d - cum[k]) / seg if seg > 0.0 else 0.0
        return float(xy[k, 0] + f * (xy[k + 1, 0] - xy[k, 0])), float(xy[k, 1] + f * (xy[k + 1, 1] - xy[k, 1]))


def _project_stops(line: np.ndarray, cum: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Distance along `line` of each point, in order and never decreasing (a loop passes a place twice: the
    next stop is searched forward from the previous one)."""
    out = np.zeros(len(pts))
    a, b = line[:-1], line[1:]
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    ll[ll == 0.0] = 1.0
    lo = 0
    for i, p in enumerate(pts):
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / ll, 0.0, 1.0)
        d2 = np.sum((a + t[:, None] * ab - p) ** 2, axis=1)
        d2[:lo] = np.inf
        best = float(np.min(d2))
        # the earliest segment about as near as the nearest: a line that comes back close later is not it
        k = int(np.argmax(d2 <= (math.sqrt(best) + 25.0) ** 2))
        out[i] = max(cum[k] + t[k] * (cum[k + 1] - cum[k]), out[i - 1] if i else 0.0)
        lo = k
    return out


def read_schedule(path: str | FsPath, *, modes: tuple[str, ...] = ("tram", "bus"),
                  bbox: tuple[float, float, float, float] | None = None,
                  window: tuple[int, int] | None = None, feed: Feed | None = None,
                  date: str | None = None) -> Schedule:
    """The feed's trips of `modes` on the service day `date` (default: the busiest of its first two weeks);
    with `bbox` (lon0, lat0, lon1, lat1) only trips that stop inside it, with `window` (service seconds) only
    departures running at some time in it. `feed`: the feed already read (`topology.gtfs.read_feed`)."""
    try:
        feed = feed if feed is not None else read_feed(path, modes)
        timetable = build_timetable(feed, date=date)
    except GtfsError as exc:
        raise ScheduleError(f"cannot read GTFS feed: {exc}") from None
    if not feed.stops:
        raise ScheduleError("the feed has no usable stops")
    stops = feed.stops
    inside = None
    if bbox is not None:
        x0, y0, x1, y1 = bbox
        inside = {sid for sid, (_n, lon, lat) in stops.items() if x0 <= lon <= x1 and y0 <= lat <= y1}
    # in the order of stop_times.txt (the local origin is the mean of their first stops: the same bits as before)
    trips = [t for t in (timetable.trips.get(tid) for tid in feed.stop_times)
             if t is not None and t.mode in modes and (inside is None or inside.intersection(t.stop_ids))]
    if not trips:
        raise ScheduleError("no trips of " + "/".join(modes) + (" inside the area" if bbox else ""))
    lon0 = float(np.mean([stops[t.stop_ids[0]][1] for t in trips]))
    lat0 = float(np.mean([stops[t.stop_ids[0]][2] for t in trips]))
    routes = {rid: r for rid, r in feed.routes.items() if r[0] in modes}
    sched = Schedule(routes, stops, {}, {}, [], lon0, lat0, timetable.service_date)
    patterns: dict[str, Pattern] = {}
    for trip in trips:
        sid = trip.shape_id
        if sid not in sched.shapes:
            xy = sched.to_xy(feed.shapes[sid][:, 0], feed.shapes[sid][:, 1])
            sched.shapes[sid] = xy
            sched.shape_cum[sid] = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
        line, cum = sched.shapes[sid], sched.shape_cum[sid]
        sxy = sched.to_xy([stops[s][1] for s in trip.stop_ids], [stops[s][2] for s in trip.stop_ids])
        patterns[trip.trip_id] = Pattern(trip.trip_id, trip.route_id, trip.direction or "0", sid, list(trip.stop_ids),
                                         trip.arr, trip.dep, _project_stops(line, cum, sxy))
    for d in timetable.departures:
        pat = patterns.get(d.trip.trip_id)
        if pat is None or (window is not None and (d.start + pat.arr[-1] < window[0] or d.start > window[1])):
            continue
        journey = f"{nmtoken(pat.trip_id)}:{d.start}" if d.frequency else nmtoken(pat.trip_id)
        sched.departures.append(Departure(journey, pat, d.start))
    sched.departures.sort(key=lambda d: (d.start, d.journey))
    return sched


def nmtoken(text: str) -> str:
    """`text` as an xsd:NMTOKEN (SIRI's journey and vehicle codes): characters outside [A-Za-z0-9._-] become
    '_' (GTFS trip ids carry spaces). ':' is kept free to separate a frequency-expanded run's start."""
    return "".join(c if c.isascii() and (c.isalnum() or c in "._-") else "_" for c in text)
