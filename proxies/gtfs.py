"""GTFS (static) reading and matching onto the topology: tram and bus shapes as a-priori routes.

Only the standard library reads the feed (csv + zipfile, streamed); pyproj projects to the artifact's CRS and
origin; the shapes that run over the map are clipped to it and map-matched onto the tram or vehicle network
by a shortest path through the corridor around each shape (`match_corridor`).
"""

from __future__ import annotations

import csv
import io
import zipfile
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path as FsPath

import numpy as np

from topology.raw import TRAM, VEHICLE

#: GTFS route_type -> our mode (basic types and the HSL extended bus types 700-704)
MODE_OF_TYPE = {0: "tram", 900: "tram", 3: "bus", 700: "bus", 701: "bus", 702: "bus", 704: "bus"}


@dataclass
class Feed:
    routes: dict[str, tuple[str, str]]  # route_id -> (mode or "", short name)
    shape_route: dict[str, str]  # shape_id -> route_id (of its first trip)
    shape_trip: dict[str, str]  # shape_id -> one trip using it
    shapes: dict[str, np.ndarray]  # shape_id -> (n, 2) lon, lat in sequence order
    stops: dict[str, tuple[str, float, float]]  # stop_id -> (name, lon, lat)
    path: str = ""


@dataclass
class MatchedShape:
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


def read_feed(path: str | FsPath, modes: tuple[str, ...] = ("tram", "bus")) -> Feed:
    """Routes, shapes, one trip per shape and the stops of the given modes."""
    with zipfile.ZipFile(path) as zf:
        routes = {}
        for r in _rows(zf, "routes.txt"):
            try:
                mode = MODE_OF_TYPE.get(int(r["route_type"]), "")
            except ValueError:
                mode = ""
            routes[r["route_id"]] = (mode, r.get("route_short_name", ""))
        shape_route: dict[str, str] = {}
        shape_trip: dict[str, str] = {}
        for t in _rows(zf, "trips.txt"):
            sid = t.get("shape_id", "")
            if sid and sid not in shape_route and routes.get(t["route_id"], ("", ""))[0] in modes:
                shape_route[sid] = t["route_id"]
                shape_trip[sid] = t["trip_id"]
        pts: dict[str, list[tuple[int, float, float]]] = defaultdict(list)
        for s in _rows(zf, "shapes.txt"):
            sid = s["shape_id"]
            if sid in shape_route:
                pts[sid].append((int(s["shape_pt_sequence"]), float(s["shape_pt_lon"]), float(s["shape_pt_lat"])))
        shapes = {sid: np.array([(lon, lat) for _q, lon, lat in sorted(p)], dtype=np.float64)
                  for sid, p in pts.items()}
        stops = {}
        for s in _rows(zf, "stops.txt"):
            try:
                stops[s["stop_id"]] = (s["stop_name"], float(s["stop_lon"]), float(s["stop_lat"]))
            except (KeyError, ValueError):
                continue
    return Feed(routes, shape_route, shape_trip, shapes, stops, str(path))


def trip_stops(path: str | FsPath, trip_ids: set[str]) -> dict[str, list[str]]:
    """Stop ids of the given trips in stop_sequence order (streams stop_times.txt once)."""
    out: dict[str, list[tuple[int, str]]] = defaultdict(list)
    with zipfile.ZipFile(path) as zf:
        for r in _rows(zf, "stop_times.txt"):
            if r["trip_id"] in trip_ids:
                out[r["trip_id"]].append((int(r["stop_sequence"]), r["stop_id"]))
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


def match_corridor(topo, xy: np.ndarray, networks: int, *, corridor: float = 25.0,
                   scale: float = 6.0) -> list[tuple[int, int]]:
    """Map-match a polyline by a shortest path through its corridor.

    Every edge of `networks` within `corridor` metres of the polyline may be used, in the direction in which
    it advances along the polyline, at a cost of length * (1 + (mean distance / scale)^2): the cheapest path
    from the node nearest the polyline's start to the node nearest its end follows the polyline, and is
    connected by construction (unlike snapping samples to the nearest edge, which flips between the two
    tracks of a double-track tram line)."""
    import networkx as nx
    import shapely

    line = shapely.LineString(xy)
    lines = shapely.from_ragged_array(shapely.GeometryType.LINESTRING, topo.edge_geom_xy,
                                      (topo.edge_geom_offsets,))
    cand = np.flatnonzero((topo.edge_networks & networks) != 0)
    cand = cand[shapely.dwithin(lines[cand], line, corridor)]
    if len(cand) == 0:
        return []
    g = nx.DiGraph()
    for e in cand.tolist():
        geom = lines[e]
        length = float(topo.edge_length[e])
        n_s = max(2, int(length / 5.0) + 1)
        pts = shapely.line_interpolate_point(geom, np.linspace(0.0, length, n_s))
        d = float(shapely.distance(pts, line).mean())
        pos = shapely.line_locate_point(line, pts[[0, -1]])
        u, v = int(topo.edge_nodes[e][0]), int(topo.edge_nodes[e][1])
        cost = length * (1.0 + (d / scale) ** 2)
        fwd = (u, v, 1) if pos[1] >= pos[0] else (v, u, -1)
        for a, b, dirn, c in ((*fwd, cost), (fwd[1], fwd[0], -fwd[2], cost * 20.0 + 50.0)):
            if a == b:
                continue
            if not g.has_edge(a, b) or g[a][b]["cost"] > c:
                g.add_edge(a, b, cost=c, edge=e, dir=dirn)
    nodes = np.array(list(g.nodes))
    nxy = topo.node_xy[nodes]
    start = int(nodes[np.argmin(np.hypot(*(nxy - xy[0]).T))])
    end = int(nodes[np.argmin(np.hypot(*(nxy - xy[-1]).T))])
    try:
        route = nx.shortest_path(g, start, end, weight="cost")
    except nx.NetworkXNoPath:
        return []
    return [(int(g[a][b]["edge"]), int(g[a][b]["dir"])) for a, b in zip(route, route[1:], strict=False)]


def match_shapes(feed: Feed, topo, *, modes: tuple[str, ...] = ("tram", "bus"), min_length: float = 300.0,
                 pad: float = 20.0) -> list[MatchedShape]:
    """Shapes of `modes` that run over the map, clipped and matched to connected directed-edge routes.

    A matched route is kept if it is at least `min_length` metres long and within -20%/+25% of the clipped
    shape's length (otherwise the match went astray and it is skipped)."""
    from topology.projection import LocalProjection

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
