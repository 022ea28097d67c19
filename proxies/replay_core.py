"""The replay producer's world (sans-IO): simulated vehicles running a GTFS schedule late or early.

Every departure of the schedule becomes a vehicle with its own delay, a random walk from stop to stop (seeded by
the journey id, so a run is reproducible and every query at any time sees the same future). Between stops it
accelerates, cruises and brakes along the trip's shape (a trapezoidal speed profile that fits the stop-to-stop
time exactly); at each stop it dwells. `now` is a service-day second throughout.

What a tracking system knows is what `visits` answers: for each requested stop the vehicles due there, each
with the expected arrival at that stop, rounded to the ETA granularity (one minute for the reference's system).
The vehicle's *next* stop gets its true arrival (the tracker sees where it is); stops further on get the
schedule plus the vehicle's current delay, which is how real predictors are wrong. `truth` answers where every
vehicle really is.
"""

from __future__ import annotations

import hashlib
import math
import random
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from proxies.schedule import Departure, Schedule

ACCEL = 1.0  # m/s^2 of the simulated vehicles
BRAKE = 1.0
VMAX = {"tram": 14.0, "bus": 17.0}
DWELL = (10.0, 30.0)  # seconds at a stop


@dataclass(frozen=True)
class Visit:
    """One vehicle due at one stop (a SIRI MonitoredStopVisit, a GTFS-rt StopTimeUpdate)."""

    stop_id: str
    vehicle: str  # VehicleRef ("" when the vehicle is not traced)
    line: str  # LineRef (GTFS route_id)
    direction: str
    journey: str  # FramedVehicleJourneyRef/DatedVehicleJourneyRef (GTFS trip id, @start when expanded)
    trip_id: str  # the GTFS trip (template) id
    order: int  # the stop's position in the journey (VisitNumber), from 1
    aimed_arrival: float  # service seconds
    expected_arrival: float
    expected_departure: float
    at_stop: bool
    monitored: bool
    lon: float | None = None  # VehicleLocation when the producer gives it
    lat: float | None = None
    mode: str = "bus"


def _profile_distance(L: float, T: float, tau: float, a: float = ACCEL, b: float = BRAKE) -> float:
    """Distance after `tau` of a trapezoidal run over L metres in exactly T seconds (accelerate at a, cruise,
    brake at b). When T is too short for that, a constant speed L/T (the schedule is then unphysical)."""
    if T <= 0.0 or L <= 0.0:
        return L if tau >= T else 0.0
    tau = min(max(tau, 0.0), T)
    c = 0.5 * (1.0 / a + 1.0 / b)
    disc = T * T - 4.0 * c * L
    if disc < 0.0:
        return L * tau / T
    v = (T - math.sqrt(disc)) / (2.0 * c)
    ta, tb = v / a, v / b
    if tau <= ta:
        return 0.5 * a * tau * tau
    if tau <= T - tb:
        return 0.5 * a * ta * ta + v * (tau - ta)
    r = T - tau
    return L - 0.5 * b * r * r


def min_run_time(L: float, vmax: float, a: float = ACCEL, b: float = BRAKE) -> float:
    """The shortest time over L metres from standstill to standstill at most at vmax."""
    if L <= 0.0:
        return 0.0
    c = 0.5 * (1.0 / a + 1.0 / b)
    tri = 2.0 * math.sqrt(c * L)  # triangle: accelerate then brake
    v_tri = tri / (2.0 * c)
    if v_tri <= vmax:
        return tri
    return L / vmax + c * vmax


class Run:
    """One vehicle on one departure: true arrival and departure times at every stop."""

    __slots__ = ("dep", "vehicle", "traced", "arr_t", "dep_t", "delay_at", "mode")

    def __init__(self, dep: Departure, mode: str, traced: bool, vehicle: str, rng: random.Random,
                 delay_sigma: float, step_sigma: float) -> None:
        self.dep = dep
        self.mode = mode
        self.vehicle = vehicle
        self.traced = traced
        pat = dep.pattern
        n = len(pat.stop_ids)
        vmax = VMAX.get(mode, 15.0)
        d = max(min(rng.gauss(0.0, delay_sigma), 4.0 * delay_sigma), -delay_sigma)  # late more than early
        arr = np.empty(n)
        dpt = np.empty(n)
        delays = np.empty(n)
        t_prev = None
        for k in range(n):
            sched_arr = dep.start + pat.arr[k]
            if k:
                d += rng.gauss(0.0, step_sigma)
            a = sched_arr + d
            if t_prev is not None:
                a = max(a, t_prev + min_run_time(pat.stop_dist[k] - pat.stop_dist[k - 1], vmax) * 1.15 + 2.0)
            d = a - sched_arr
            dwell = rng.uniform(*DWELL) if 0 < k < n - 1 else 0.0
            dep_t = a + dwell
            arr[k], dpt[k], delays[k] = a, dep_t, d
            t_prev = dep_t
        self.arr_t, self.dep_t, self.delay_at = arr, dpt, delays

    @property
    def begin(self) -> float:
        """Arrival time at the first stop (service-day seconds): the first SIRI visit of the run."""
        return float(self.arr_t[0])

    @property
    def end(self) -> float:
        """Arrival time at the last stop (service-day seconds): the run is over after it."""
        return float(self.arr_t[-1])

    def distance(self, now: float) -> tuple[float, int, bool]:
        """(metres along the shape, index of the last stop reached, standing at it) at `now`."""
        pat = self.dep.pattern
        k = bisect_right(self.arr_t, now) - 1
        if k < 0:
            return float(pat.stop_dist[0]), 0, True
        if k >= len(self.arr_t) - 1 or now <= self.dep_t[k]:
            return float(pat.stop_dist[k]), k, True
        L = float(pat.stop_dist[k + 1] - pat.stop_dist[k])
        T = float(self.arr_t[k + 1] - self.dep_t[k])
        return float(pat.stop_dist[k]) + _profile_distance(L, T, now - float(self.dep_t[k])), k, False


class ReplayWorld:
    """Every departure of a schedule as a simulated vehicle. Queries are pure functions of `now`."""

    def __init__(self, schedule: Schedule, *, seed: int = 1, delay_sigma: float = 90.0, step_sigma: float = 20.0,
                 granularity: float = 60.0, traced_bus_fraction: float = 0.5, locations: bool = False) -> None:
        self.schedule = schedule
        self.seed = seed
        self.delay_sigma = float(delay_sigma)
        self.step_sigma = float(step_sigma)
        self.granularity = float(granularity)
        self.locations = locations
        self.runs: list[Run] = []
        for i, dep in enumerate(schedule.departures):
            h = int.from_bytes(hashlib.sha256(f"{seed}:{dep.journey}".encode()).digest()[:8], "big")
            rng = random.Random(h)
            mode = schedule.routes.get(dep.pattern.route_id, ("bus", ""))[0] or "bus"
            traced = mode == "tram" or rng.random() < traced_bus_fraction
            self.runs.append(Run(dep, mode, traced, f"{'T' if mode == 'tram' else 'B'}{i:05d}", rng,
                                 self.delay_sigma, self.step_sigma))
        self.by_stop: dict[str, list[tuple[Run, int]]] = {}
        for run in self.runs:
            for k, sid in enumerate(run.dep.pattern.stop_ids):
                self.by_stop.setdefault(sid, []).append((run, k))
        order = np.argsort([r.begin for r in self.runs])
        self._begin = np.array([self.runs[i].begin for i in order])
        self._order = [self.runs[int(i)] for i in order]
        self._longest = max((r.end - r.begin for r in self.runs), default=0.0)

    def active(self, now: float) -> list[Run]:
        """Runs between their first arrival and their last (on the road now)."""
        hi = int(np.searchsorted(self._begin, now, side="right"))
        lo = int(np.searchsorted(self._begin, now - self._longest, side="left"))
        return [r for r in self._order[lo:hi] if r.end >= now]

    def truth(self, now: float) -> dict[str, tuple[float, float, str]]:
        """vehicle -> (lon, lat, journey) of every vehicle on the road."""
        out = {}
        for run in self.active(now):
            d, _k, _at = run.distance(now)
            x, y = self.schedule.point_on_shape(run.dep.pattern.shape_id, d)
            lon, lat = self.schedule.to_lonlat(x, y)
            out[run.vehicle] = (lon, lat, run.dep.journey)
        return out

    def _eta(self, t: float) -> float:
        g = self.granularity
        return round(t / g) * g if g > 0.0 else t

    def visit(self, run: Run, k: int, now: float) -> Visit | None:
        """The visit of `run` at its k-th stop as the tracker reports it at `now` (None when it has left)."""
        if now > run.dep_t[k] or now < run.begin - 1800.0:
            return None
        pat = run.dep.pattern
        _d, last, at = run.distance(now)
        aimed = run.dep.start + float(pat.arr[k])
        if now < run.begin:
            expected = aimed + float(run.delay_at[0])
        elif k <= last + 1:
            expected = float(run.arr_t[k])  # the next stop (or the one it stands at): the tracker knows
        else:
            expected = aimed + float(run.delay_at[last])  # further on: schedule plus the delay now
        exp_dep = expected + float(run.dep_t[k] - run.arr_t[k])
        at_stop = bool(at and last == k and now >= run.arr_t[k])
        lon = lat = None
        if self.locations and run.traced and now >= run.begin:
            x, y = self.schedule.point_on_shape(pat.shape_id, _d)
            lon, lat = self.schedule.to_lonlat(x, y)
        route_mode = self.schedule.routes.get(pat.route_id, ("bus", ""))[0] or "bus"
        return Visit(pat.stop_ids[k], run.vehicle if run.traced else "", pat.route_id, pat.direction,
                     run.dep.journey, pat.trip_id, k + 1, aimed, self._eta(expected),
                     max(self._eta(exp_dep), self._eta(expected)), at_stop, run.traced, lon, lat, route_mode)

    def visits(self, stop_ids, now: float, preview: float = 1800.0, max_visits: int | None = None) -> list[Visit]:
        """The visits due at each stop within `preview` seconds, earliest first per stop."""
        out: list[Visit] = []
        for sid in stop_ids:
            got = []
            for run, k in self.by_stop.get(sid, ()):
                if run.arr_t[k] - preview > now or run.dep_t[k] < now:
                    continue
                v = self.visit(run, k, now)
                if v is not None:
                    got.append(v)
            got.sort(key=lambda v: v.expected_arrival)
            out.extend(got[:max_visits] if max_visits else got)
        return out

    def vehicle_states(self, now: float) -> list[tuple[Run, float, float, int, bool]]:
        """(run, lon, lat, last stop index, standing) of every traced vehicle on the road (GTFS-rt positions)."""
        out = []
        for run in self.active(now):
            if not run.traced:
                continue
            d, k, at = run.distance(now)
            x, y = self.schedule.point_on_shape(run.dep.pattern.shape_id, d)
            lon, lat = self.schedule.to_lonlat(x, y)
            out.append((run, lon, lat, k, at))
        return out
