"""The schedule model: a GTFS feed's trips with their stop times, and one service day's departures.

Why in topology: the simulation spawns every departure of a service day and the transit proxies replay and
follow them; both need the same trips, times and frequency runs, and `sims` and `proxies` import nothing of
each other. The feed is read once by `topology.gtfs.read_feed`; `build_timetable` turns it into the model,
without the map (placing trips on the map is each user's own concern: spawn points for the simulation,
shapes and stop distances for the proxies).

Times are integer seconds since the service day's midnight, hours past 24 kept (a trip of the service day
that runs after midnight). A trip's stop times are relative to its first departure; a stop that the feed
leaves without a time (not a timepoint) gets one interpolated between its timed neighbours by stop count.
frequencies.txt is expanded: a trip with frequencies runs from each `start_time` every `headway_secs` while
before `end_time` (its own stop times are only the pattern); `exact_times=1` runs are scheduled exactly, the
others are headway-based service, expanded the same way and marked (`Departure.exact`). Trips with fewer than
two known stops, times that run backwards, or no service on the day are skipped and counted in the report.
"""

from __future__ import annotations

import datetime as dt
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from topology.gtfs import Feed, GtfsError

__all__ = ["Departure", "Timetable", "Trip", "build_timetable", "service_day"]


@dataclass
class Trip:
    """One trip of the feed (a template, when it has frequencies): its stops, and the arrival and departure
    at each in seconds after its first departure (`first`, a service-day second)."""

    trip_id: str
    route_id: str
    mode: str
    ref: str  # the route's short name
    direction: str  # direction_id ("" when the feed has none)
    shape_id: str  # `Feed.shapes` key (shapes.txt's, or the one made of its stops)
    stop_ids: list[str]
    arr: np.ndarray  # float64 seconds after `first`
    dep: np.ndarray
    first: int


@dataclass(frozen=True)
class Departure:
    """One run of a trip: `start` is the service-day second of its first departure; `frequency`: expanded from
    frequencies.txt (several runs of one trip, told apart by their start), `exact`: at exactly that time
    (exact_times=1, or a trip without frequencies)."""

    trip: Trip
    start: int
    frequency: bool = False
    exact: bool = True


@dataclass
class Timetable:
    """The trips running on the service day (in trips.txt order) and their departures, sorted by start then
    trip id so that runs are deterministic; `report` counts what was skipped and why (the feed's counts too)."""

    trips: dict[str, Trip]
    departures: list[Departure]
    service_date: str = ""
    report: Counter = field(default_factory=Counter)


def _active(feed: Feed, day: str) -> set[str]:
    wd = dt.datetime.strptime(day, "%Y%m%d").weekday()
    out = {s for s, (days, a, b) in feed.calendar.items() if a <= day <= b and days[wd]}
    for s, kind in feed.calendar_dates.get(day, {}).items():
        (out.add if kind == 1 else out.discard)(s)
    return out


def service_day(feed: Feed, date: str | None = None) -> tuple[set[str] | None, str]:
    """(service ids running on `date` (YYYYMMDD), the date); without a date, the busiest of the feed's first
    14 days. (None, "") when the feed has no calendar at all (every trip runs)."""
    if not feed.calendar and not feed.calendar_dates:
        return None, ""
    try:
        if date is None:
            starts = [a for _d, a, _b in feed.calendar.values()] + list(feed.calendar_dates)
            first = dt.datetime.strptime(min(starts), "%Y%m%d")
            days = [(first + dt.timedelta(days=i)).strftime("%Y%m%d") for i in range(14)]
            date = max(days, key=lambda d: (len(_active(feed, d)), -int(d)))
        return _active(feed, date), date
    except ValueError:
        raise GtfsError(f"not a service date (YYYYMMDD): {date!r}") from None


def _times(rows: list[tuple[int, str, int | None, int | None]]) -> tuple[list[float], list[float]] | None:
    """Arrival and departure at each row, the untimed ones interpolated by stop count; None when the first or
    the last has no time or a time runs backwards."""
    timed = [k for k, r in enumerate(rows) if r[2] is not None]
    if not timed or timed[0] != 0 or timed[-1] != len(rows) - 1:
        return None
    arr = [float(r[2]) if r[2] is not None else 0.0 for r in rows]
    dep = [float(max(r[3], r[2])) if r[2] is not None else 0.0 for r in rows]
    for a, b in zip(timed, timed[1:], strict=False):
        for k in range(a + 1, b):
            arr[k] = dep[k] = dep[a] + (arr[b] - dep[a]) * (k - a) / (b - a)
    if any(arr[k] < dep[k - 1] for k in range(1, len(rows))):
        return None
    return arr, dep


def build_timetable(feed: Feed, *, date: str | None = None) -> Timetable:
    """The trips of `feed` running on the service day `date` (default: `service_day`'s busiest) and their
    departures, frequencies expanded."""
    report = Counter(feed.report)
    services, service_date = service_day(feed, date)
    trips: dict[str, Trip] = {}
    out: list[Departure] = []
    for tid, info in feed.trips.items():
        if services is not None and info.service_id not in services:
            report["skipped:not_in_service"] += 1
            continue
        rows = [r for r in feed.stop_times.get(tid, []) if r[1] in feed.stops]
        if len(rows) < 2:
            report["skipped:trip_with_fewer_than_two_stops"] += 1
            continue
        times = _times(rows)
        if times is None:
            report["skipped:trip_times_missing_or_backwards"] += 1
            continue
        arr, dep = times
        first = int(dep[0])
        mode, ref = feed.routes[info.route_id]
        trip = trips[tid] = Trip(tid, info.route_id, mode, ref, info.direction, info.shape_id,
                                 [r[1] for r in rows], np.array(arr) - first, np.array(dep) - first, first)
        runs = feed.frequencies.get(tid)
        if not runs:
            out.append(Departure(trip, first))
            continue
        n = len(out)
        for a, b, h, exact in runs:
            out.extend(Departure(trip, start, True, exact) for start in range(a, b, h))
        report["read:frequency_trips_expanded"] += len(out) - n
    out.sort(key=lambda d: (d.start, d.trip.trip_id))
    report["read:departures"] = len(out)
    return Timetable(trips, out, service_date, report)
