"""GTFS (static) reading and matching onto the topology: tram and bus shapes as a-priori routes.

Only the standard library reads the feed (csv + zipfile, streamed); pyproj projects to the artifact's CRS and
origin; the shapes that run over the map are clipped to it and map-matched onto the tram or vehicle network
by a shortest path through the corridor around each shape (`topology.matching.match_corridor`, the same
matcher as OSM route relations).

Files: routes.txt, trips.txt, stops.txt and stop_times.txt are required (a feed without one is refused with a
`GtfsError` naming it); shapes.txt and every other file are optional. A trip without a shape (no shapes.txt,
no shape_id, or a shape_id that shapes.txt lacks) is routed from stop to stop on the network: shortest paths
between the nodes nearest its consecutive stops (`topology.matching.route_by_stops`). Malformed rows are
skipped and counted in `Feed.report`.
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


class GtfsError(ValueError):
    """The feed cannot be read (not a zip, a required file missing): a clear message for the user."""

#: GTFS route_type -> our mode (basic types and the HSL extended bus types 700-704)
MODE_OF_TYPE = {0: "tram", 900: "tram", 3: "bus", 700: "bus", 701: "bus", 702: "bus", 704: "bus"}


@dataclass
class Feed:
    """What `read_feed` keeps of a feed: the routes, shapes and stops of the wanted modes (lon, lat)."""

    routes: dict[str, tuple[str, str]]  # route_id -> (mode or "", short name)
    shape_route: dict[str, str]  # shape_id -> route_id (of its first trip)
    shape_trip: dict[str, str]  # shape_id -> one trip using it
    shapes: dict[str, np.ndarray]  # shape_id -> (n, 2) lon, lat in sequence order
    stops: dict[str, tuple[str, float, float]]  # stop_id -> (name, lon, lat)
    path: str = ""
    #: "skipped:<file>_bad_row", "read:trips_without_shape", ...
    report: Counter = field(default_factory=Counter)


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


def read_feed(path: str | FsPath, modes: tuple[str, ...] = ("tram", "bus")) -> Feed:
    """Routes, shapes, one trip per shape and the stops of the given modes.

    Trips without a usable shape get one made of their stops (`STOP_SHAPE` + trip id; one trip per route and
    direction), which `match_shapes` routes from stop to stop on the network."""
    report: Counter = Counter()
    with _open(path) as zf:
        routes = {}
        for r in _rows(zf, "routes.txt"):
            try:
                mode = MODE_OF_TYPE.get(int(r["route_type"]), "")
                routes[r["route_id"]] = (mode, r.get("route_short_name") or "")
            except (KeyError, TypeError, ValueError):
                report["skipped:routes_bad_row"] += 1
        shape_route: dict[str, str] = {}
        shape_trip: dict[str, str] = {}
        shapeless: dict[tuple[str, str], str] = {}  # (route, direction) -> one trip without a shape
        for t in _rows(zf, "trips.txt"):
            try:
                rid, tid = t["route_id"], t["trip_id"]
            except KeyError:
                report["skipped:trips_bad_row"] += 1
                continue
            if routes.get(rid, ("", ""))[0] not in modes or not tid:
                continue
            sid = t.get("shape_id") or ""
            if sid:
                if sid not in shape_route:
                    shape_route[sid] = rid
                    shape_trip[sid] = tid
            else:
                shapeless.setdefault((rid, t.get("direction_id") or ""), tid)
        pts: dict[str, list[tuple[int, float, float]]] = defaultdict(list)
        if "shapes.txt" in zf.namelist():
            for s in _rows(zf, "shapes.txt"):
                sid = s.get("shape_id") or ""
                if sid in shape_route:
                    try:
                        pts[sid].append((int(s["shape_pt_sequence"]), float(s["shape_pt_lon"]),
                                         float(s["shape_pt_lat"])))
                    except (KeyError, TypeError, ValueError):
                        report["skipped:shapes_bad_row"] += 1
        shapes = {sid: np.array([(lon, lat) for _q, lon, lat in sorted(p)], dtype=np.float64)
                  for sid, p in pts.items() if len(p) >= 2}
        for sid in list(shape_route):  # a shape_id that shapes.txt lacks: route its trip by its stops
            if sid not in shapes:
                rid = shape_route.pop(sid)
                shapeless.setdefault((rid, sid), shape_trip.pop(sid))
        stops = {}
        for s in _rows(zf, "stops.txt"):
            try:
                stops[s["stop_id"]] = (s.get("stop_name") or "", float(s["stop_lon"]), float(s["stop_lat"]))
            except (KeyError, TypeError, ValueError):
                report["skipped:stops_bad_row"] += 1
    if shapeless:
        report["read:trips_without_shape"] += len(shapeless)
        seqs = trip_stops(path, set(shapeless.values()), report)
        for (rid, _d), tid in sorted(shapeless.items()):
            known = [stops[i] for i in seqs.get(tid, []) if i in stops]
            if len(known) >= 2:
                sid = STOP_SHAPE + tid
                shape_route[sid], shape_trip[sid] = rid, tid
                shapes[sid] = np.array([(k[1], k[2]) for k in known], dtype=np.float64)
    return Feed(routes, shape_route, shape_trip, shapes, stops, str(path), report)


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
    shape's length (otherwise the match went astray and it is skipped). A trip without a shape is routed
    from stop to stop (`route_by_stops`) and kept if it is at least `min_length` metres long."""
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
        stops_of = trip_stops(feed.path, {feed.shape_trip[m.shape_id] for m in out})
        for m in out:
            ids = stops_of.get(feed.shape_trip[m.shape_id], [])
            known = [feed.stops[i] for i in ids if i in feed.stops]
            if known:
                sxy = proj.to_local(np.array([k[1] for k in known]), np.array([k[2] for k in known]))
                m.stop_xy = [(k[0], float(p[0]), float(p[1])) for k, p in zip(known, sxy, strict=True)]
    return out
