"""A-priori routes of the proxied vehicles: GTFS trips matched onto the map's network, with their stops as
path coordinates.

`proxies.gtfs.match_shapes` matches each shape that runs over the map to a connected chain of directed edges;
here every trip of the schedule (`proxies.schedule`) that uses a matched shape gets that chain as its route (a
trip without a shape has the one made of its stops, matched from stop to stop: `topology.gtfs`), and
each of its stops that lies along the chain (within `stop_snap` metres) its path coordinate `s`, never
decreasing in the trip's stop order. The SIRI/GTFS-rt journey reference (`nmtoken(trip id)`, and `:start` for a
frequency run) finds the trip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path as FsPath

import numpy as np

from proxies.schedule import Pattern, Schedule, ScheduleError, nmtoken, read_schedule


@dataclass
class RouteStop:
    """A trip's stop placed on its route's path coordinate, with the schedule times the ETA motion
    falls back on past the tracker's last ETA."""
    stop_id: str
    index: int  # position in the trip's stop list (SIRI Order - 1)
    s: float  # path coordinate on the route
    sched_arr: float  # seconds from the trip's first departure
    sched_dep: float
    approach_speed: float = 6.0  # m/s of the schedule from the trip's previous stop (on the map or not)


@dataclass
class TransitRoute:
    """A matched shape as a chain of directed edges (the vehicles' a-priori path) with the stops
    along it; shared by the trips that use that shape and stop list."""
    shape_id: str
    mode: str  # "tram" | "bus"
    edges: list[tuple[int, int]]
    length: float
    stops: list[RouteStop] = field(default_factory=list)  # in travel order, s non-decreasing


@dataclass
class RouteBook:
    """Trip -> route lookups for the proxies, and the stops to poll."""

    routes: dict[str, TransitRoute]  # trip id -> route (shared by trips of one shape and stop list)
    journey_trip: dict[str, str]  # nmtoken(trip id) -> trip id
    stops: list[str]  # every stop on a route, to poll
    line_mode: dict[str, str]
    schedule: Schedule | None = None

    def route_of(self, journey: str) -> tuple[str, TransitRoute] | None:
        """(trip id, route) of a journey reference (a plain or nmtoken'd trip id, `:start` optional)."""
        for key in (journey, journey.rsplit(":", 1)[0]):
            tid = self.journey_trip.get(key, key)
            r = self.routes.get(tid)
            if r is not None:
                return tid, r
        return None


def _path_xy(topo, edges: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """The route's polyline (local metres) and cumulative length, edge geometry in travel direction."""
    pts = []
    for e, d in edges:
        p = topo.edge_polyline(e)
        pts.append(p if d > 0 else p[::-1])
    xy = np.concatenate(pts)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    return xy, cum


def _stops_along(xy: np.ndarray, cum: np.ndarray, pts: np.ndarray, snap: float) -> list[float | None]:
    """Path coordinate of each point in order (never decreasing), None where it is farther than `snap`."""
    a, b = xy[:-1], xy[1:]
    ab = b - a
    ll = np.einsum("ij,ij->i", ab, ab)
    ll[ll == 0.0] = 1e-12
    out: list[float | None] = []
    lo = 0
    for p in pts:
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / ll, 0.0, 1.0)
        d2 = np.sum((a + t[:, None] * ab - p) ** 2, axis=1)
        d2[:lo] = np.inf
        k = int(np.argmin(d2))
        if not math.isfinite(d2[k]) or d2[k] > snap * snap:
            out.append(None)
            continue
        out.append(float(cum[k] + t[k] * (cum[k + 1] - cum[k])))
        lo = k
    return out


def _approach(pat: Pattern, k: int) -> float:
    """The schedule's mean speed from stop k-1 to stop k (along the shape), within 2..15 m/s."""
    if k == 0:
        return 6.0
    run = float(pat.arr[k] - pat.dep[k - 1])
    gap = float(pat.stop_dist[k] - pat.stop_dist[k - 1])
    return min(max(gap / run, 2.0), 15.0) if run > 0.0 and gap > 0.0 else 6.0


def build_routes(topo, gtfs: str | FsPath, *, modes: tuple[str, ...] = ("tram", "bus"), stop_snap: float = 40.0,
                 schedule: Schedule | None = None, matched=None) -> RouteBook:
    """Match the feed's shapes onto `topo` and give every trip over the map its route and stops."""
    from proxies.gtfs import GtfsError, match_shapes, read_feed
    from topology.projection import LocalProjection

    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    feed = None
    if matched is None or schedule is None:  # the feed read once, for the matching and the schedule
        try:
            feed = read_feed(gtfs, modes=modes)
        except GtfsError as exc:
            raise ScheduleError(f"cannot read GTFS feed: {exc}") from None
    if matched is None:
        matched = match_shapes(feed, topo, modes=modes)
    if schedule is None:
        x0, y0, x1, y1 = topo.meta["bounds"]
        ll = proj.to_wgs84(np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]], dtype=np.float64))
        bbox = (float(ll[:, 0].min()), float(ll[:, 1].min()), float(ll[:, 0].max()), float(ll[:, 1].max()))
        schedule = read_schedule(gtfs, modes=modes, bbox=bbox, feed=feed)
    by_shape: dict[str, list] = {}
    for m in matched:
        by_shape.setdefault(m.shape_id, []).append(m)
    patterns: dict[str, Pattern] = {}
    for dep in schedule.departures:
        patterns.setdefault(dep.pattern.trip_id, dep.pattern)
    routes: dict[str, TransitRoute] = {}
    memo: dict[tuple[str, tuple[str, ...]], TransitRoute | None] = {}
    line_mode: dict[str, str] = {}
    stop_set: dict[str, None] = {}
    for tid, pat in patterns.items():
        runs = by_shape.get(pat.shape_id)
        if not runs:
            continue
        key = (pat.shape_id, tuple(pat.stop_ids))
        if key not in memo:
            best = None
            sxy = proj.to_local(np.array([schedule.stops[s][1] for s in pat.stop_ids]),
                                np.array([schedule.stops[s][2] for s in pat.stop_ids]))
            for m in runs:
                xy, cum = _path_xy(topo, m.edges)
                ss = _stops_along(xy, cum, sxy, stop_snap)
                stops = [RouteStop(sid, k, s, float(pat.arr[k]), float(pat.dep[k]), _approach(pat, k))
                         for k, (sid, s) in enumerate(zip(pat.stop_ids, ss, strict=True)) if s is not None]
                if len(stops) >= 2 and (best is None or len(stops) > len(best.stops)):
                    best = TransitRoute(m.shape_id, m.mode, list(m.edges), float(cum[-1]), stops)
            memo[key] = best
        r = memo[key]
        if r is None:
            continue
        routes[tid] = r
        line_mode[pat.route_id] = r.mode
        for st in r.stops:
            stop_set[st.stop_id] = None
    journey_trip = {nmtoken(t): t for t in routes}
    return RouteBook(routes, journey_trip, list(stop_set), line_mode, schedule)


def cached_routes(topo, gtfs: str | FsPath, *, modes: tuple[str, ...] = ("tram", "bus"), say=None) -> RouteBook:
    """`build_routes`, cached on disk (the entitynet cache folder) by the map's digest, the feed's content, the
    modes and this package's source, so a proxy starts in a second after the first time. An unreadable cache
    entry is rebuilt."""
    import hashlib
    import pickle

    from entitynet.topology_cache import cache_dir

    h = hashlib.sha256()
    h.update(topo.digest.encode())
    h.update(FsPath(gtfs).read_bytes())
    h.update(",".join(modes).encode())
    import topology.gtfs
    import topology.schedule

    for src in [*sorted(FsPath(__file__).parent.glob("*.py")), FsPath(topology.gtfs.__file__),
                FsPath(topology.schedule.__file__)]:  # this package's source and the feed's reader and model
        h.update(src.read_bytes())
    path = cache_dir() / f"routes-{h.hexdigest()[:16]}.pickle"
    if path.exists():
        try:
            with open(path, "rb") as fh:
                book = pickle.load(fh)
            if isinstance(book, RouteBook):
                return book
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
            pass
    if say:
        say("matching the feed's shapes onto the map (cached for the next start)")
    book = build_routes(topo, gtfs, modes=modes)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        with open(tmp, "wb") as fh:
            pickle.dump(book, fh, protocol=pickle.HIGHEST_PROTOCOL)
        tmp.replace(path)
    except OSError:
        pass
    return book
