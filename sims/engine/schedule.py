"""Spawning from schedules: the departures of a GTFS feed's trams and buses onto the map.

Why here and not in the transit proxy: the proxy follows live vehicles; the simulation needs every trip of a
service day as a spawn event, expanded from frequencies.txt, with times past 24:00 kept (a trip of the service
day that runs after midnight), entering at the map's edge when it starts outside (its shape is clipped to the
map and matched onto the network) and leaving at the edge. The feed is read and the shapes are matched by the
project's one GTFS reader and map matcher (`topology.gtfs`).

Times are seconds since the service day's midnight. A trip's spawn time is when it reaches the map: the time
of its first stop on the map less the time to drive there at the kind's cruise speed (or, when it crosses
without stopping, from the nearest stop of its own). Each stop keeps its timetable arrival (seconds after the
spawn time), from which the world derives the speed between stops (`behaviour.timetable_speed`).
Malformed rows, unknown route types, trips that never touch the map and trips outside the service day are
skipped and counted in `Schedule.report`.
"""

from __future__ import annotations

import csv
import datetime as dt
import io
import random
import zipfile
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
from topology.gtfs import STOP_SHAPE, GtfsError, match_shapes, read_feed

__all__ = ["Departure", "GtfsError", "Schedule", "parse_time", "read_schedule"]

#: a stop belongs to a matched route when it is within this many metres of it
STOP_SNAP = 30.0


def parse_time(text: str) -> float:
    """GTFS "H:MM:SS" to seconds since the service day's midnight; hours past 24 are kept (25:10:00 is
    90600). A clear ValueError otherwise."""
    parts = text.strip().split(":")
    if len(parts) != 3:
        raise ValueError(f"not a GTFS time: {text!r}")
    h, m, s = (int(p) for p in parts)
    if h < 0 or not 0 <= m < 60 or not 0 <= s < 61:
        raise ValueError(f"not a GTFS time: {text!r}")
    return float(h * 3600 + m * 60 + s)


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


def _rows(zf: zipfile.ZipFile, name: str):
    with zf.open(name) as fh:
        yield from csv.DictReader(io.TextIOWrapper(fh, encoding="utf-8-sig", newline=""))


def _services(zf: zipfile.ZipFile, date: str | None, report: Counter) -> tuple[set[str] | None, str]:
    """Service ids running on `date` (YYYYMMDD); without a date, the busiest of the feed's first 14 days.
    None when the feed has no calendar at all (every trip runs)."""
    names = zf.namelist()
    cal: dict[str, tuple[list[int], str, str]] = {}
    if "calendar.txt" in names:
        for r in _rows(zf, "calendar.txt"):
            try:
                days = [int(r[d]) for d in ("monday", "tuesday", "wednesday", "thursday", "friday", "saturday",
                                            "sunday")]
                cal[r["service_id"]] = (days, r["start_date"], r["end_date"])
            except (KeyError, ValueError):
                report["skipped:calendar_bad_row"] += 1
    extra: dict[str, dict[str, int]] = defaultdict(dict)
    if "calendar_dates.txt" in names:
        for r in _rows(zf, "calendar_dates.txt"):
            try:
                extra[r["date"]][r["service_id"]] = int(r["exception_type"])
            except (KeyError, ValueError):
                report["skipped:calendar_dates_bad_row"] += 1
    if not cal and not extra:
        return None, ""

    def active(day: str) -> set[str]:
        wd = dt.datetime.strptime(day, "%Y%m%d").weekday()
        out = {s for s, (days, a, b) in cal.items() if a <= day <= b and days[wd]}
        for s, kind_ in extra.get(day, {}).items():
            (out.add if kind_ == 1 else out.discard)(s)
        return out

    if date is None:
        starts = [a for _d, a, _b in cal.values()] + list(extra)
        first = dt.datetime.strptime(min(starts), "%Y%m%d")
        days = [(first + dt.timedelta(days=i)).strftime("%Y%m%d") for i in range(14)]
        date = max(days, key=lambda d: (len(active(d)), -int(d)))
    try:
        return active(date), date
    except ValueError:
        raise GtfsError(f"not a service date (YYYYMMDD): {date!r}") from None


def read_schedule(path: str | Path, topo, *, modes: tuple[str, ...] = ("tram", "bus"), date: str | None = None,
                  seed: int = 1) -> Schedule:
    """Every departure of `modes` on the service day `date` whose trip runs over the map."""
    net = netview(topo)
    rng = random.Random(seed)
    feed = read_feed(path, modes)
    report: Counter = Counter(feed.report)
    matched = match_shapes(feed, topo, modes=modes)
    runs: dict[str, list] = defaultdict(list)
    for m in matched:
        runs[m.shape_id].append(m)
    from topology.projection import LocalProjection

    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    stop_ids = sorted(feed.stops)
    sxy = proj.to_local(np.array([feed.stops[i][1] for i in stop_ids]), np.array([feed.stops[i][2] for i in stop_ids]))
    stop_xy = {sid: (float(p[0]), float(p[1])) for sid, p in zip(stop_ids, sxy, strict=True)}

    with zipfile.ZipFile(path) as zf:
        services, service_date = _services(zf, date, report)
        stopless: dict[tuple[str, str], str] = {}
        for sid in feed.shapes:
            if sid.startswith(STOP_SHAPE):
                stopless.setdefault((feed.shape_route[sid], ""), sid)
        trips: dict[str, tuple[str, str]] = {}  # trip -> (route, shape key)
        for t in _rows(zf, "trips.txt"):
            rid, tid = t.get("route_id", ""), t.get("trip_id", "")
            if rid not in feed.routes or not tid:
                report["skipped:trips_bad_row"] += 1
                continue
            mode = feed.routes[rid][0]
            if not mode:
                report["skipped:unknown_route_type"] += 1
                continue
            if mode not in modes:
                continue
            if services is not None and t.get("service_id") not in services:
                report["skipped:not_in_service"] += 1
                continue
            sid = t.get("shape_id") or ""
            if sid not in feed.shapes:
                sid = STOP_SHAPE + tid if STOP_SHAPE + tid in feed.shapes else stopless.get((rid, ""), "")
            if sid not in runs:
                report["skipped:trip_off_map"] += 1
                continue
            trips[tid] = (rid, sid)
        times: dict[str, list[tuple[int, str, float, float]]] = defaultdict(list)
        for r in _rows(zf, "stop_times.txt"):
            tid = r.get("trip_id")
            if tid not in trips:
                continue
            try:
                arr = parse_time(r.get("arrival_time") or r["departure_time"])
                dep = parse_time(r.get("departure_time") or r["arrival_time"])
                times[tid].append((int(r["stop_sequence"]), r["stop_id"], arr, max(dep, arr)))
            except (KeyError, ValueError):
                report["skipped:stop_times_bad_row"] += 1
        freqs: dict[str, list[tuple[float, float, float]]] = defaultdict(list)
        if "frequencies.txt" in zf.namelist():
            for r in _rows(zf, "frequencies.txt"):
                try:
                    a, b, h = parse_time(r["start_time"]), parse_time(r["end_time"]), float(r["headway_secs"])
                    if h <= 0 or b < a:
                        raise ValueError
                    freqs[r["trip_id"]].append((a, b, h))
                except (KeyError, ValueError):
                    report["skipped:frequencies_bad_row"] += 1

    placed: dict[tuple[str, int], tuple[Route, dict[str, float]]] = {}
    out: list[Departure] = []
    for tid in sorted(trips):
        rid, sid = trips[tid]
        st = sorted(times.get(tid, []))
        if not st:
            report["skipped:trip_without_stop_times"] += 1
            continue
        mode, ref = feed.routes[rid][0], feed.routes[rid][1]
        k = kind(mode)
        starts = [st[0][3]]
        for a, b, h in freqs.get(tid, []):
            starts.extend(a + i * h for i in range(int((b - a) // h) + (1 if (b - a) % h else 0)))
        if freqs.get(tid):
            starts = starts[1:]  # the template's own times are only a pattern
            report["read:frequency_trips_expanded"] += len(starts)
        for ri, m in enumerate(runs[sid]):
            key = (sid, ri)
            if key not in placed:
                placed[key] = (Route(net, list(m.edges)), {})
            route, snap = placed[key]
            on: list[tuple[float, str, float, float]] = []
            for _q, stop, arr, dep in st:
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
                near = min(st, key=lambda x: _dist(stop_xy.get(x[1]), route.xy(0.0)))
                t_enter = near[3] + _dist(stop_xy.get(near[1]), route.xy(0.0)) / k.cruise
            stops = tuple(Stop(s, max(dep - arr, rng.uniform(*k.halts.dwell)) if k.halts else dep - arr,
                               feed.stops[stop][0], arr - t_enter)
                          for s, stop, arr, dep in on if s < route.length - 1.0)
            for t0 in starts:
                out.append(Departure(t_enter + (t0 - st[0][3]), tid if len(starts) == 1 else f"{tid}@{int(t0)}",
                                     mode, ref, tuple(route.edges), stops))
    report["departures"] = len(out)
    if not out:
        report["warning:no_departure_over_the_map"] += 1
    return Schedule(out, report, service_date)


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

    if cache is None:
        return read_schedule(path, topo, date=date, seed=seed)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise GtfsError(f"{path}: cannot read the feed ({exc.strerror})") from None
    h = hashlib.sha256(data)
    h.update(f"{topo.digest}|{date}|{seed}".encode())
    h.update(Path(__file__).read_bytes())
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
