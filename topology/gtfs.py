"""GTFS (static): the project's one reader of a feed's files, and the matching of its shapes onto the topology.

Why one reader: the simulation (spawns), the transit proxies (routes, the replay producer) and the benchmarks
all read the same feed; each parsing the CSV itself gave two `Schedule` classes, two time parsers and rules
that disagreed (a feed without shapes.txt had one stop-made shape per route and direction here but one per
trip in the proxy, so the proxy placed 53 of 2,077 trips). `read_feed` reads every file once (csv + zipfile,
streamed, standard library only) into a `Feed`; `topology.schedule` makes the service day's departures of it;
`match_shapes` clips the shapes that run over the map and matches them onto the tram or vehicle network by a
shortest path through the corridor around each (`topology.matching.match_corridor`, the same matcher as OSM
route relations).

Files: routes.txt, trips.txt, stops.txt and stop_times.txt are required (a feed without one is refused with a
`GtfsError` naming it); shapes.txt, frequencies.txt, calendar.txt, calendar_dates.txt and the rest are
optional. A trip without a shape (no shapes.txt, no shape_id, or a shape_id that shapes.txt lacks) runs on the
shape made of its stops: one per route and stop sequence, named `STOP_SHAPE` + the first (smallest) id of the
trips that share it, so that every such trip finds the shape `match_shapes` matched; it is routed from stop to
stop on the network (`topology.matching.route_by_stops`). Malformed rows are skipped and counted in
`Feed.report`.
"""

from __future__ import annotations

import csv
import io
import zipfile
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path as FsPath

import numpy as np

from topology.matching import match_corridor, network_graph, route_by_stops
from topology.networks import TRAM, VEHICLE

REQUIRED_FILES = ("routes.txt", "trips.txt", "stops.txt", "stop_times.txt")
#: shape ids made for trips without a shape: their polyline is the trip's stops
STOP_SHAPE = "stops:"
WEEKDAYS = ("monday", "tuesday", "wednesday", "thursday", "friday", "saturday", "sunday")


class GtfsError(ValueError):
    """The feed cannot be read (not a zip, a required file missing, a bad time): a clear message for the user."""

#: GTFS route_type -> our mode (basic types and the HSL extended bus types 700-704)
MODE_OF_TYPE = {0: "tram", 900: "tram", 3: "bus", 700: "bus", 701: "bus", 702: "bus", 704: "bus"}


def parse_time(text: str) -> int:
    """GTFS "H:MM:SS" to seconds since the service day's midnight (noon minus 12 h); hours past 24 are kept
    (25:10:00 is 90600: a trip of the service day that runs after midnight). A GtfsError otherwise."""
    parts = text.strip().split(":")
    try:
        if len(parts) != 3 or not all(p.isdigit() for p in parts):
            raise ValueError
        h, m, s = (int(p) for p in parts)
        if not (0 <= m < 60 and 0 <= s < 61):
            raise ValueError
    except ValueError:
        raise GtfsError(f"not a GTFS time: {text!r}") from None
    return h * 3600 + m * 60 + s


@dataclass
class TripInfo:
    """A trip of trips.txt: its route, service, direction and the shape it runs on (shapes.txt's, or the
    `STOP_SHAPE` one made of its stops; "" when it has neither)."""

    route_id: str
    service_id: str
    direction: str
    shape_id: str


@dataclass
class Feed:
    """What `read_feed` keeps of a feed: the routes, stops and shapes (lon, lat) of the wanted modes' trips,
    with their stop times, frequencies and calendars."""

    routes: dict[str, tuple[str, str]]  # route_id -> (mode or "", short name)
    shape_route: dict[str, str]  # shape_id -> route_id (of its first trip)
    shape_trip: dict[str, str]  # shape_id -> one trip using it
    shapes: dict[str, np.ndarray]  # shape_id -> (n, 2) lon, lat in sequence order
    stops: dict[str, tuple[str, float, float]]  # stop_id -> (name, lon, lat)
    path: str = ""
    #: "skipped:<file>_bad_row", "read:trips_without_shape", ...
    report: Counter = field(default_factory=Counter)
    trips: dict[str, TripInfo] = field(default_factory=dict)  # trip_id -> info, in trips.txt order
    #: trip_id -> [(stop_sequence, stop_id, arrival, departure)] sorted; a time is None where the feed leaves it
    #: empty (a stop that is not a timepoint)
    stop_times: dict[str, list[tuple[int, str, int | None, int | None]]] = field(default_factory=dict)
    #: trip_id -> [(start, end, headway, exact_times)] of frequencies.txt
    frequencies: dict[str, list[tuple[int, int, int, bool]]] = field(default_factory=dict)
    #: service_id -> (Monday..Sunday flags, start date, end date) of calendar.txt
    calendar: dict[str, tuple[tuple[int, ...], str, str]] = field(default_factory=dict)
    #: date -> {service_id: exception_type (1 added, 2 removed)} of calendar_dates.txt
    calendar_dates: dict[str, dict[str, int]] = field(default_factory=dict)


@dataclass
class MatchedShape:
    """One shape (or stop sequence) that runs over the map, clipped to it and matched onto the network."""

    shape_id: str
    route_id: str
    mode: str
    ref: str
    xy: np.ndarray  # the clipped shape in local coordinates
    edges: list[tuple[int, int]]  # connected directed edges (the a-priori route)
    stop_xy: list[tuple[str, float, float]] = field(default_factory=list)  # (name, x, y) in travel order


def _rows(zf: zipfile.ZipFile, name: str):
    with zf.open(name) as fh:
        yield from csv.DictReader(io.TextIOWrapper(fh, encoding="utf-8-sig", newline=""))


def read_table(zf: zipfile.ZipFile, name: str) -> tuple[list[str], list[dict[str, str]]]:
    """One file of an open feed as it is: its column names and rows (for tools that rewrite a feed, such as
    the bundled extract's `sims.data.make_hsl_extract`, so that no one else parses the CSV)."""
    with zf.open(name) as fh:
        r = csv.DictReader(io.TextIOWrapper(fh, encoding="utf-8-sig", newline=""))
        return list(r.fieldnames or []), list(r)


def _open(path: str | FsPath) -> zipfile.ZipFile:
    try:
        zf = zipfile.ZipFile(path)
    except (OSError, zipfile.BadZipFile) as exc:
        raise GtfsError(f"{path}: not a readable GTFS zip ({exc})") from None
    missing = [n for n in REQUIRED_FILES if n not in zf.namelist()]
    if missing:
        zf.close()
        raise GtfsError(f"{path}: not a complete GTFS feed, required file(s) missing: {', '.join(missing)}")
    return zf


def _optional_time(text: str | None) -> int | None:
    return parse_time(text) if text and text.strip() else None


def read_feed(path: str | FsPath, modes: tuple[str, ...] = ("tram", "bus")) -> Feed:
    """Every file of the feed that the project uses, for the trips of the given modes: routes, trips, their
    stop times, frequencies, the calendars, stops, and shapes (a trip without one gets the shape of its
    stops: the module docstring)."""
    report: Counter = Counter()
    feed = Feed({}, {}, {}, {}, {}, str(path), report)
    with _open(path) as zf:
        names = set(zf.namelist())
        for r in _rows(zf, "routes.txt"):
            try:
                feed.routes[r["route_id"]] = (MODE_OF_TYPE.get(int(r["route_type"]), ""),
                                              r.get("route_short_name") or "")
            except (KeyError, TypeError, ValueError):
                report["skipped:routes_bad_row"] += 1
        for t in _rows(zf, "trips.txt"):
            rid, tid = t.get("route_id"), t.get("trip_id")
            if not rid or not tid or rid not in feed.routes:
                report["skipped:trips_bad_row"] += 1
                continue
            mode = feed.routes[rid][0]
            if not mode:
                report["skipped:unknown_route_type"] += 1
            elif mode in modes:
                feed.trips[tid] = TripInfo(rid, t.get("service_id") or "", t.get("direction_id") or "",
                                           t.get("shape_id") or "")
        _read_stop_times(zf, feed)
        if "frequencies.txt" in names:
            for r in _rows(zf, "frequencies.txt"):
                if r.get("trip_id") not in feed.trips:
                    continue
                try:
                    a, b, h = parse_time(r["start_time"]), parse_time(r["end_time"]), int(r["headway_secs"])
                    if h <= 0 or b < a:
                        raise ValueError
                    feed.frequencies.setdefault(r["trip_id"], []).append((a, b, h, r.get("exact_times") == "1"))
                except (KeyError, TypeError, ValueError):
                    report["skipped:frequencies_bad_row"] += 1
        _read_calendars(zf, names, feed)
        for s in _rows(zf, "stops.txt"):
            try:
                feed.stops[s["stop_id"]] = (s.get("stop_name") or "", *_lonlat(s["stop_lon"], s["stop_lat"]))
            except (KeyError, TypeError, ValueError):
                report["skipped:stops_bad_row"] += 1
        wanted = {t.shape_id for t in feed.trips.values() if t.shape_id}
        pts: dict[str, list[tuple[int, float, float]]] = defaultdict(list)
        if "shapes.txt" in names:
            for s in _rows(zf, "shapes.txt"):
                sid = s.get("shape_id") or ""
                if sid in wanted:
                    try:
                        pts[sid].append((int(s["shape_pt_sequence"]), *_lonlat(s["shape_pt_lon"],
                                                                                s["shape_pt_lat"])))
                    except (KeyError, TypeError, ValueError):
                        report["skipped:shapes_bad_row"] += 1
    feed.shapes = {sid: np.array([(lon, lat) for _q, lon, lat in sorted(p)], dtype=np.float64)
                   for sid, p in pts.items() if len(p) >= 2}
    _assign_shapes(feed)
    return feed


def _lonlat(lon_text: str, lat_text: str) -> tuple[float, float]:
    """A WGS84 position from a row, or ValueError: one NaN stop made every shape built from stops all NaN."""
    lon, lat = float(lon_text), float(lat_text)
    if not (-180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0):  # also False for NaN
        raise ValueError(f"coordinate out of range: {lon_text}, {lat_text}")
    return lon, lat


def _read_stop_times(zf: zipfile.ZipFile, feed: Feed) -> None:
    """stop_times.txt of the wanted trips, each trip's rows in stop_sequence order (bad rows counted)."""
    out: dict[str, list[tuple[int, str, int | None, int | None]]] = defaultdict(list)
    for r in _rows(zf, "stop_times.txt"):
        tid = r.get("trip_id")
        if tid not in feed.trips:
            continue
        try:
            arr = _optional_time(r.get("arrival_time"))
            dep = _optional_time(r.get("departure_time"))
            out[tid].append((int(r["stop_sequence"]), r["stop_id"], arr if arr is not None else dep,
                             dep if dep is not None else arr))
        except (KeyError, TypeError, ValueError):
            feed.report["skipped:stop_times_bad_row"] += 1
    feed.stop_times = {tid: _by_sequence(rows, feed.report) for tid, rows in out.items()}


def _by_sequence(rows: list[tuple[int, str, int | None, int | None]],
                 report: Counter) -> list[tuple[int, str, int | None, int | None]]:
    """One trip's rows in stop_sequence order; a repeated stop_sequence keeps its first row and counts the rest
    as bad rows (sorting whole rows compared an untimed row's None with a time: TypeError)."""
    kept: dict[int, tuple[int, str, int | None, int | None]] = {}
    for row in rows:
        if row[0] in kept:
            report["skipped:stop_times_bad_row"] += 1
        else:
            kept[row[0]] = row
    return [kept[q] for q in sorted(kept)]


def _read_calendars(zf: zipfile.ZipFile, names: set[str], feed: Feed) -> None:
    if "calendar.txt" in names:
        for r in _rows(zf, "calendar.txt"):
            try:
                days = tuple(int(r[d]) for d in WEEKDAYS)
                feed.calendar[r["service_id"]] = (days, r["start_date"], r["end_date"])
            except (KeyError, TypeError, ValueError):
                feed.report["skipped:calendar_bad_row"] += 1
    if "calendar_dates.txt" in names:
        for r in _rows(zf, "calendar_dates.txt"):
            try:
                feed.calendar_dates.setdefault(r["date"], {})[r["service_id"]] = int(r["exception_type"])
            except (KeyError, TypeError, ValueError):
                feed.report["skipped:calendar_dates_bad_row"] += 1


def _assign_shapes(feed: Feed) -> None:
    """Each trip's shape: shapes.txt's, else the one made of its stops (per route and stop sequence)."""
    made: dict[tuple[str, tuple[str, ...]], list[str]] = defaultdict(list)
    for tid, t in feed.trips.items():
        if t.shape_id in feed.shapes:
            if t.shape_id not in feed.shape_route:
                feed.shape_route[t.shape_id], feed.shape_trip[t.shape_id] = t.route_id, tid
            continue
        seq = tuple(s for _q, s, _a, _d in feed.stop_times.get(tid, []) if s in feed.stops)
        t.shape_id = ""
        if len(seq) >= 2:
            made[(t.route_id, seq)].append(tid)
        feed.report["read:trips_without_shape"] += 1
    for (rid, seq), tids in made.items():
        sid = STOP_SHAPE + min(tids)
        feed.shapes[sid] = np.array([feed.stops[s][1:] for s in seq], dtype=np.float64)
        feed.shape_route[sid], feed.shape_trip[sid] = rid, min(tids)
        for tid in tids:
            feed.trips[tid].shape_id = sid
    if made:
        feed.report["read:shapes_made_of_stops"] += len(made)


def trip_stops(path: str | FsPath, trip_ids: set[str], report: Counter | None = None) -> dict[str, list[str]]:
    """Stop ids of the given trips in stop_sequence order (streams stop_times.txt once; bad rows skipped)."""
    out: dict[str, list[tuple[int, str]]] = defaultdict(list)
    with _open(path) as zf:
        for r in _rows(zf, "stop_times.txt"):
            tid = r.get("trip_id")
            if tid in trip_ids:
                try:
                    out[tid].append((int(r["stop_sequence"]), r["stop_id"]))
                except (KeyError, TypeError, ValueError):
                    if report is not None:
                        report["skipped:stop_times_bad_row"] += 1
    return {t: [s for _q, s in sorted(v)] for t, v in out.items()}


def _inside_runs(xy: np.ndarray, bounds: tuple[float, float, float, float], pad: float) -> list[np.ndarray]:
    x0, y0, x1, y1 = bounds
    inside = (xy[:, 0] >= x0 + pad) & (xy[:, 0] <= x1 - pad) & (xy[:, 1] >= y0 + pad) & (xy[:, 1] <= y1 - pad)
    runs, cur = [], []
    for p, ok in zip(xy, inside, strict=True):
        if ok:
            cur.append(p)
        elif cur:
            runs.append(np.array(cur))
            cur = []
    if cur:
        runs.append(np.array(cur))
    return runs


def match_shapes(feed: Feed, topo, *, modes: tuple[str, ...] = ("tram", "bus"), min_length: float = 300.0,
                 pad: float = 20.0) -> list[MatchedShape]:
    """Shapes of `modes` that run over the map, clipped and matched to connected directed-edge routes.

    A matched route is kept if it is at least `min_length` metres long and within -20%/+25% of the clipped
    shape's length (otherwise the match went astray and it is skipped). A shape made of a trip's stops is
    routed from stop to stop (`route_by_stops`) and kept if it is at least `min_length` metres long."""
    from topology.projection import LocalProjection

    graphs: dict[int, object] = {}

    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    bounds = tuple(topo.meta["bounds"])
    out: list[MatchedShape] = []
    for sid in sorted(feed.shapes):
        route_id = feed.shape_route[sid]
        mode, ref = feed.routes[route_id]
        if mode not in modes:
            continue
        bits = TRAM if mode == "tram" else VEHICLE
        xy = proj.to_local(feed.shapes[sid][:, 0], feed.shapes[sid][:, 1])
        for run in _inside_runs(xy, bounds, pad):
            if len(run) < 2:
                continue
            seg = float(np.hypot(*np.diff(run, axis=0).T).sum())
            if seg < min_length:
                continue
            if sid.startswith(STOP_SHAPE):
                if bits not in graphs:
                    graphs[bits] = network_graph(topo, bits)
                best = route_by_stops(topo, graphs[bits], run)
                length = float(sum(topo.edge_length[e] for e, _ in best))
                if length < min_length:
                    continue
            else:
                best = match_corridor(topo, run, bits)
                length = float(sum(topo.edge_length[e] for e, _ in best))
                if length < min_length or not 0.8 * seg <= length <= 1.25 * seg:
                    continue
            out.append(MatchedShape(sid, route_id, mode, ref, run, best))
    if out:
        stops_of = {tid: [s for _q, s, _a, _d in feed.stop_times.get(tid, [])]
                    for tid in {feed.shape_trip[m.shape_id] for m in out}}
        if not feed.stop_times:  # a Feed made by hand, without its stop times: stream them
            stops_of = trip_stops(feed.path, set(stops_of))
        for m in out:
            ids = stops_of.get(feed.shape_trip[m.shape_id], [])
            known = [feed.stops[i] for i in ids if i in feed.stops]
            if known:
                sxy = proj.to_local(np.array([k[1] for k in known]), np.array([k[2] for k in known]))
                m.stop_xy = [(k[0], float(p[0]), float(p[1])) for k, p in zip(known, sxy, strict=True)]
    return out
