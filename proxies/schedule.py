"""A GTFS schedule as the replay producer and the proxies need it: trips with their stop times, frequencies
expanded into departures, and each trip's shape with the distance of every stop along it.

Only the standard library and numpy read the feed (csv + zipfile, streamed). `proxies.gtfs` does the shape
*matching* onto a topology; this module keeps the schedule itself, in the feed's own coordinates (WGS84), with
distances in metres from a local equirectangular projection around the feed's centre (exact to well under
0.1 % across a city, and cheap).
"""

from __future__ import annotations

import csv
import io
import math
import zipfile
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path as FsPath

import numpy as np

from proxies.gtfs import MODE_OF_TYPE

EARTH_R = 6_371_008.8


class ScheduleError(ValueError):
    """A feed that cannot be used (missing files or columns, no trips)."""


def parse_gtfs_time(text: str) -> int:
    """"HH:MM:SS" (hours may pass 24) -> seconds after the service day's noon-minus-12h."""
    try:
        h, m, s = (int(p) for p in text.strip().split(":"))
    except ValueError:
        raise ScheduleError(f"bad GTFS time {text!r}") from None
    return h * 3600 + m * 60 + s


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
    service_date: str  # YYYYMMDD of the first calendar entry

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


def _rows(zf: zipfile.ZipFile, name: str):
    try:
        fh = zf.open(name)
    except KeyError:
        raise ScheduleError(f"the feed has no {name}") from None
    with fh:
        yield from csv.DictReader(io.TextIOWrapper(fh, encoding="utf-8-sig", newline=""))


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
                  window: tuple[int, int] | None = None) -> Schedule:
    """The feed's trips of `modes`; with `bbox` (lon0, lat0, lon1, lat1) only trips that stop inside it, with
    `window` (service seconds) only departures running at some time in it. Frequencies (exact_times or not)
    are expanded into departures every headway."""
    try:
        zf = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile) as exc:
        raise ScheduleError(f"cannot read GTFS feed {path}: {exc}") from None
    with zf:
        routes: dict[str, tuple[str, str]] = {}
        for r in _rows(zf, "routes.txt"):
            try:
                mode = MODE_OF_TYPE.get(int(r["route_type"]), "")
            except ValueError:
                mode = ""
            if mode in modes:
                routes[r["route_id"]] = (mode, r.get("route_short_name", ""))
        stops: dict[str, tuple[str, float, float]] = {}
        for s in _rows(zf, "stops.txt"):
            try:
                stops[s["stop_id"]] = (s.get("stop_name", ""), float(s["stop_lon"]), float(s["stop_lat"]))
            except (KeyError, ValueError):
                continue
        if not stops:
            raise ScheduleError("the feed has no usable stops")
        inside = None
        if bbox is not None:
            x0, y0, x1, y1 = bbox
            inside = {sid for sid, (_n, lon, lat) in stops.items() if x0 <= lon <= x1 and y0 <= lat <= y1}
        trips: dict[str, tuple[str, str, str]] = {}
        for t in _rows(zf, "trips.txt"):
            if t["route_id"] in routes:
                trips[t["trip_id"]] = (t["route_id"], t.get("direction_id", "0") or "0", t.get("shape_id", ""))
        times: dict[str, list[tuple[int, str, int, int]]] = defaultdict(list)
        for r in _rows(zf, "stop_times.txt"):
            tid = r["trip_id"]
            if tid in trips:
                arr = r.get("arrival_time") or r.get("departure_time") or ""
                dep = r.get("departure_time") or arr
                if not arr:
                    continue
                times[tid].append((int(r["stop_sequence"]), r["stop_id"], parse_gtfs_time(arr), parse_gtfs_time(dep)))
        freqs: dict[str, list[tuple[int, int, int]]] = defaultdict(list)
        if "frequencies.txt" in zf.namelist():
            for f in _rows(zf, "frequencies.txt"):
                freqs[f["trip_id"]].append((parse_gtfs_time(f["start_time"]), parse_gtfs_time(f["end_time"]),
                                            int(f["headway_secs"])))
        date = ""
        if "calendar.txt" in zf.namelist():
            for c in _rows(zf, "calendar.txt"):
                date = c.get("start_date", "")
                break
        shape_pts: dict[str, list[tuple[int, float, float]]] = defaultdict(list)
        patterns: list[tuple[Pattern, int]] = []
        for tid, rows in times.items():
            rows.sort()
            ids = [r[1] for r in rows if r[1] in stops]
            if len(ids) < 2 or (inside is not None and not inside.intersection(ids)):
                continue
            rows = [r for r in rows if r[1] in stops]
            t0 = rows[0][3]
            route_id, direction, shape_id = trips[tid]
            pat = Pattern(tid, route_id, direction, shape_id, ids,
                          np.array([r[2] - t0 for r in rows], dtype=np.float64),
                          np.array([r[3] - t0 for r in rows], dtype=np.float64))
            patterns.append((pat, t0))
        wanted_shapes = {p.shape_id for p, _ in patterns if p.shape_id}
        if "shapes.txt" in zf.namelist():
            for s in _rows(zf, "shapes.txt"):
                if s["shape_id"] in wanted_shapes:
                    shape_pts[s["shape_id"]].append((int(s["shape_pt_sequence"]), float(s["shape_pt_lon"]),
                                                     float(s["shape_pt_lat"])))
    if not patterns:
        raise ScheduleError("no trips of " + "/".join(modes) + (" inside the area" if bbox else ""))
    lon0 = float(np.mean([stops[p.stop_ids[0]][1] for p, _ in patterns]))
    lat0 = float(np.mean([stops[p.stop_ids[0]][2] for p, _ in patterns]))
    sched = Schedule(routes, stops, {}, {}, [], lon0, lat0, date)
    for sid, pts in shape_pts.items():
        pts.sort()
        xy = sched.to_xy([p[1] for p in pts], [p[2] for p in pts])
        sched.shapes[sid] = xy
        sched.shape_cum[sid] = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    for pat, t0 in patterns:
        if not pat.shape_id or pat.shape_id not in sched.shapes:
            # no shape: straight lines from stop to stop make one
            pat.shape_id = "stops:" + pat.trip_id
            xy = sched.to_xy([stops[s][1] for s in pat.stop_ids], [stops[s][2] for s in pat.stop_ids])
            sched.shapes[pat.shape_id] = xy
            sched.shape_cum[pat.shape_id] = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
        line, cum = sched.shapes[pat.shape_id], sched.shape_cum[pat.shape_id]
        sxy = sched.to_xy([stops[s][1] for s in pat.stop_ids], [stops[s][2] for s in pat.stop_ids])
        pat.stop_dist = _project_stops(line, cum, sxy) if len(line) >= 2 else np.zeros(len(sxy))
        runs = freqs.get(pat.trip_id)
        starts = []
        if runs:
            for a, b, h in runs:
                if h > 0:
                    starts.extend(range(a, b, h))
        else:
            starts = [t0]
        for st in starts:
            if window is not None and (st + pat.arr[-1] < window[0] or st > window[1]):
                continue
            journey = nmtoken(pat.trip_id) if not runs else f"{nmtoken(pat.trip_id)}:{st}"
            sched.departures.append(Departure(journey, pat, int(st)))
    sched.departures.sort(key=lambda d: (d.start, d.journey))
    return sched


def nmtoken(text: str) -> str:
    """`text` as an xsd:NMTOKEN (SIRI's journey and vehicle codes): characters outside [A-Za-z0-9._-] become
    '_' (GTFS trip ids carry spaces). ':' is kept free to separate a frequency-expanded run's start."""
    return "".join(c if c.isascii() and (c.isalnum() or c in "._-") else "_" for c in text)
