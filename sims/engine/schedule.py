"""Spawning from schedules: the departures of a GTFS feed's trams and buses onto the map.

Why here and not in the transit proxy: the proxy follows live vehicles; the simulation needs every trip of a
service day as a spawn event, entering at the map's edge when it starts outside (its shape is clipped to the
map and matched onto the network) and leaving at the edge. The feed is read, its frequencies expanded and its
service day chosen by the project's one GTFS reader and schedule model (`topology.gtfs`, `topology.schedule`);
the shapes are matched by its one map matcher. This module only places the departures on the map.

Times are seconds since the service day's midnight. A trip's spawn time is when it reaches the map: the time
of its first stop on the map less the time to drive there at the kind's cruise speed (or, when it crosses
without stopping, from the nearest stop of its own). Each stop keeps its timetable arrival (seconds after the
spawn time), from which the world derives the speed between stops (`behaviour.timetable_speed`).
Malformed rows, unknown route types, trips that never touch the map and trips outside the service day are
skipped and counted in `Schedule.report`.
"""

from __future__ import annotations

import random
from bisect import bisect_right
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from entitynet.client import netview
from entitynet.client.network import DirEdge
from sims.engine.agents import Stop
from sims.engine.routes import Route
from sims.mobility.kinds import kind
from topology.gtfs import GtfsError, match_shapes, read_feed
from topology.schedule import build_timetable

__all__ = ["Departure", "GtfsError", "Schedule", "read_schedule"]

#: a stop belongs to a matched route when it is within this many metres of it
STOP_SNAP = 30.0


@dataclass(frozen=True)
class Departure:
    """One vehicle to spawn: at `time` (service-day seconds) at the start of `edges`, halting at `stops`
    (their `arrive`: the timetable's arrival in seconds after `time`)."""

    time: float
    trip_id: str
    mode: str
    ref: str
    edges: tuple[DirEdge, ...]
    stops: tuple[Stop, ...]


@dataclass
class Schedule:
    """The service day's departures over the map, sorted by time (then trip id, so runs are deterministic)
    for `due`'s bisection; `report` counts what was skipped and why."""

    departures: list[Departure]
    report: Counter = field(default_factory=Counter)
    service_date: str = ""

    def __post_init__(self) -> None:
        self.departures.sort(key=lambda d: (d.time, d.trip_id))
        self._times = [d.time for d in self.departures]

    def due(self, after: float, until: float) -> list[Departure]:
        """Departures with after < time <= until."""
        return self.departures[bisect_right(self._times, after):bisect_right(self._times, until)]

    def running_at(self, t: float, max_age: float = 3600.0) -> list[Departure]:
        """Departures that started in the `max_age` seconds before `t` (a run starting mid-day fills the map
        with the vehicles already under way)."""
        return self.due(t - max_age, t)


def read_schedule(path: str | Path, topo, *, modes: tuple[str, ...] = ("tram", "bus"), date: str | None = None,
                  seed: int = 1) -> Schedule:
    """Every departure of `modes` on the service day `date` whose trip runs over the map."""
    net = netview(topo)
    rng = random.Random(seed)
    feed = read_feed(path, modes)
    timetable = build_timetable(feed, date=date)
    report: Counter = Counter(timetable.report)
    runs: dict[str, list] = defaultdict(list)
    for m in match_shapes(feed, topo, modes=modes):
        runs[m.shape_id].append(m)
    from topology.projection import LocalProjection

    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    stop_ids = sorted(feed.stops)
    sxy = proj.to_local(np.array([feed.stops[i][1] for i in stop_ids]), np.array([feed.stops[i][2] for i in stop_ids]))
    stop_xy = {sid: (float(p[0]), float(p[1])) for sid, p in zip(stop_ids, sxy, strict=True)}
    starts: dict[str, list[float]] = defaultdict(list)
    for d in timetable.departures:
        starts[d.trip.trip_id].append(float(d.start))

    placed: dict[tuple[str, int], tuple[Route, dict[str, float]]] = {}
    out: list[Departure] = []
    for tid in sorted(timetable.trips):
        trip = timetable.trips[tid]
        if trip.shape_id not in runs:
            report["skipped:trip_off_map"] += 1
            continue
        k = kind(trip.mode)
        t_first = float(trip.first)
        st = [(stop, t_first + float(a), t_first + float(d))
              for stop, a, d in zip(trip.stop_ids, trip.arr, trip.dep, strict=True)]
        for ri, m in enumerate(runs[trip.shape_id]):
            key = (trip.shape_id, ri)
            if key not in placed:
                placed[key] = (Route(net, list(m.edges)), {})
            route, snap = placed[key]
            on: list[tuple[float, str, float, float]] = []
            for stop, arr, dep in st:
                if stop not in stop_xy:
                    continue
                if stop not in snap:
                    snap[stop] = _snap(route, stop_xy[stop])
                s = snap[stop]
                if s is not None and (not on or s > on[-1][0] + 5.0):
                    on.append((s, stop, arr, dep))
            if on:
                t_enter = on[0][2] - on[0][0] / k.cruise
            else:  # crosses without stopping: from the nearest of its stops
                near = min(st, key=lambda x: _dist(stop_xy.get(x[0]), route.xy(0.0)))
                t_enter = near[2] + _dist(stop_xy.get(near[0]), route.xy(0.0)) / k.cruise
            stops = tuple(Stop(s, max(dep - arr, rng.uniform(*k.halts.dwell)) if k.halts else dep - arr,
                               feed.stops[stop][0], arr - t_enter)
                          for s, stop, arr, dep in on if s < route.length - 1.0)
            several = len(starts[tid]) != 1
            for t0 in starts[tid]:
                out.append(Departure(t_enter + (t0 - t_first), f"{tid}@{int(t0)}" if several else tid,
                                     trip.mode, trip.ref, tuple(route.edges), stops))
    report["departures"] = len(out)
    if not out:
        report["warning:no_departure_over_the_map"] += 1
    return Schedule(out, report, timetable.service_date)


def _dist(p, q) -> float:
    if p is None:
        return float("inf")
    return float(np.hypot(p[0] - q[0], p[1] - q[1]))


def _snap(route: Route, p: tuple[float, float]) -> float | None:
    """Route distance of the point of `route` nearest to p, if within STOP_SNAP metres."""
    ss = np.arange(0.0, route.length + 2.5, 2.5)
    ss[-1] = min(ss[-1], route.length)
    pts = np.array([route.xy(float(s)) for s in ss])
    d = np.hypot(pts[:, 0] - p[0], pts[:, 1] - p[1])
    i = int(np.argmin(d))
    return float(ss[i]) if d[i] <= STOP_SNAP else None


#: the schedule bundled with the package (see sims/data/HSL-GTFS-LICENSE.md)
BUNDLED_FEED = Path(__file__).resolve().parents[1] / "data" / "hsl-helsinki-centre.zip"


def load_schedule(path: str | Path, topo, *, date: str | None = None, cache: Path | None = None,
                  seed: int = 1) -> Schedule:
    """`read_schedule`, cached as JSON under `cache` (keyed by the feed's bytes, the map's digest, the date,
    the seed and this module's source), since matching shapes onto the map takes seconds."""
    import hashlib
    import json

    import topology.gtfs as gtfs_module
    import topology.schedule as schedule_module

    if cache is None:
        return read_schedule(path, topo, date=date, seed=seed)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise GtfsError(f"{path}: cannot read the feed ({exc.strerror})") from None
    h = hashlib.sha256(data)
    h.update(f"{topo.digest}|{date}|{seed}".encode())
    for module in (__file__, gtfs_module.__file__, schedule_module.__file__):  # the reader and model too
        h.update(Path(module).read_bytes())
    file = cache / f"schedule-{h.hexdigest()[:16]}.json"
    if file.exists():
        try:
            raw = json.loads(file.read_text())
            deps = [Departure(d[0], d[1], d[2], d[3], tuple((e, s) for e, s in d[4]),
                              tuple(Stop(*st) for st in d[5])) for d in raw["departures"]]
            return Schedule(deps, Counter(raw["report"]), raw["service_date"])
        except (OSError, ValueError, KeyError, TypeError):
            pass  # unreadable cache: rebuild it
    sched = read_schedule(path, topo, date=date, seed=seed)
    try:
        cache.mkdir(parents=True, exist_ok=True)
        tmp = file.with_suffix(".tmp")
        tmp.write_text(json.dumps({
            "departures": [[d.time, d.trip_id, d.mode, d.ref, [list(e) for e in d.edges],
                            [[st.s, st.dwell, st.name, st.arrive] for st in d.stops]] for d in sched.departures],
            "report": dict(sched.report), "service_date": sched.service_date}))
        tmp.replace(file)
    except OSError:
        pass  # a read-only cache only costs the next run the matching again
    return sched
