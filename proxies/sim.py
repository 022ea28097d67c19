"""Replay producer -> proxy core in virtual time, measured against the replay's truth (the benchmark's engine,
and a deterministic test of the whole chain without sockets).

Every poll, the world's visits at the route stops go through the real wire format (`build_response` then
`parse_response`) into the fleet; every second the fleet moves and publishes, and where a viewer sees each
proxied vehicle (its published model, extrapolated) is compared with where the replay has it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from proxies.fleet import Fleet
from proxies.replay_core import ReplayWorld
from proxies.routes import RouteBook
from proxies.siri_xml import ServiceClock, build_response, parse_response


@dataclass
class SimResult:
    """What a virtual-time run measured: position errors against the truth, publishes, CPU and the
    error over time (for the outage's recovery)."""
    errors: list[float] = field(default_factory=list)
    publishes: int = 0
    vehicle_seconds: float = 0.0
    cpu_s: float = 0.0
    seen: set[str] = field(default_factory=set)
    lost: int = 0
    series: list[tuple[float, float]] = field(default_factory=list)  # (seconds from start, mean error then)

    def summary(self) -> dict:
        """The report's figures: error mean/p95/max, updates per vehicle minute, CPU per vehicle hour."""
        e = np.array(self.errors) if self.errors else np.zeros(1)
        vmin = self.vehicle_seconds / 60.0
        vh = self.vehicle_seconds / 3600.0
        return {
            "position_error_m": {"mean": float(e.mean()), "p95": float(np.percentile(e, 95)), "max": float(e.max()),
                                 "samples": len(self.errors)},
            "updates_per_vehicle_min": self.publishes / vmin if vmin else 0.0,
            "proxy_cpu_s_per_vehicle_hour": self.cpu_s / vh if vh else 0.0,
            "vehicles_traced": len(self.seen),
        }


def run_sim(topo, book: RouteBook, world: ReplayWorld, *, start: float, duration: float, poll: float = 20.0,
            latency: float = 3.0, warmup: float = 120.0, outage: tuple[float, float] | None = None,
            fleet_kw: dict | None = None, preview: float = 300.0) -> tuple[SimResult, Fleet]:
    """Run from service second `start` for `duration` s (errors counted after `warmup`). `outage` = (from, to)
    seconds after start during which polls fail."""
    from topology.projection import LocalProjection

    clock = ServiceClock.for_date(book.schedule.service_date if book.schedule else "20220222")
    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    fleet = Fleet(topo, book, **{"granularity": world.granularity, **(fleet_kw or {})})
    res = SimResult()
    stops = book.stops

    def to_local(lon, lat):
        p = proj.to_local(np.array([lon]), np.array([lat]))[0]
        return float(p[0]), float(p[1])

    next_poll = start
    t = start
    while t <= start + duration:
        now = clock.epoch(t)
        c0 = time.process_time()
        if t >= next_poll:
            next_poll += poll
            failing = outage is not None and outage[0] <= t - start < outage[1]
            if not failing:
                data = build_response(world.visits(stops, t - latency, preview=preview), t - latency, clock)
                c0 = time.process_time()
                d = parse_response(data)
                fleet.ingest(d.calls, d.response_time, now, to_local=to_local)
        fleet.tick(now)
        res.cpu_s += time.process_time() - c0
        res.vehicle_seconds += len(fleet.vehicles)
        if t - start >= warmup and fleet.vehicles:
            truth = world.truth(t)
            refs = [r for r in fleet.vehicles if r in truth]
            if refs:
                ll = np.array([truth[r][:2] for r in refs])
                txy = proj.to_local(ll[:, 0], ll[:, 1])
                errs = []
                for r, (tx, ty) in zip(refs, txy, strict=True):
                    g = fleet.ghost_xy(r, now)
                    if g is not None:
                        errs.append(float(np.hypot(g[0] - tx, g[1] - ty)))
                res.errors.extend(errs)
                if errs:
                    res.series.append((t - start, float(np.mean(errs))))
        t += 1.0
    res.publishes = fleet.counters.publishes
    res.seen = set(fleet.counters.vehicles_seen)
    res.lost = fleet.counters.retired_stale
    return res, fleet
