"""`entitynet bench proxy [--quick] --out FILE.json`: speed against error of the SIRI transit proxy.

The replay producer runs the HSL schedule (trams and buses) over the bundled map; the proxy core reads its SIRI
answers (the real XML both ways) every `poll` seconds, `latency` seconds old, and publishes each vehicle through
its client core. Where a viewer sees each vehicle (its published model) is compared every second with the
replay's truth. Virtual time: the clock is stepped, so an hour of service takes a fraction of that and the
figures do not depend on the machine's load; CPU is the process time of the proxy's work alone (parsing,
ingest, motion, client cores), not of the producer.

Results: `vehicles_traced`, `discarded_fraction`, `position_error_m` per poll (10, 20, 60 s) and ETA
granularity (60 s, 1 s), `updates_per_vehicle_min`, `proxy_cpu_s_per_vehicle_hour` (and what 2,000 vehicles
would take of one core), `recovery_s` after a 2-minute outage and `vehicles_lost` over it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

FEED_CANDIDATES = ("../shared/data/hsl-gtfs-2022-02.zip",)


def find_feed() -> Path:
    """The HSL GTFS feed the benchmark replays: ENTITYNET_GTFS, then ../shared/data, then ENTITYNET_SHARED;
    a clear error naming them when none exists."""
    env = os.environ.get("ENTITYNET_GTFS")
    cands = [env] if env else []
    root = Path(__file__).resolve().parents[1]
    for c in FEED_CANDIDATES:
        cands += [c, str(root / c)]
    shared = os.environ.get("ENTITYNET_SHARED")
    if shared:
        cands.append(str(Path(shared) / "data" / "hsl-gtfs-2022-02.zip"))
    for c in cands:
        if c and Path(c).exists():
            return Path(c)
    raise FileNotFoundError("no GTFS feed: set ENTITYNET_GTFS (or have ../shared/data/hsl-gtfs-2022-02.zip)")


def recovery(series: list[tuple[float, float]], outage: tuple[float, float], warmup: float) -> float | None:
    """Seconds after the outage's end until the 30 s mean error is back within 20 % (+5 m) of its mean before
    the outage; None if it never is."""
    before = [e for t, e in series if warmup <= t < outage[0]]
    if not before:
        return None
    limit = 1.2 * float(np.mean(before)) + 5.0
    after = [(t, e) for t, e in series if t >= outage[1]]
    for i, (t, _e) in enumerate(after):
        window = [e for t2, e in after[i:] if t2 < t + 30.0]
        if window and float(np.mean(window)) <= limit:
            return t - outage[1]
    return None


def measure_recovery(topo, book, *, outage: float, poll: float, progress) -> dict:
    """Real HTTP on loopback: the replay producer, the proxy shell (zeep, our WSDL) and a real server. The
    tracker answers 503 for `outage` seconds; `recovery_s` is the time from its end until the proxy has a good
    answer again (it polls on, so at most a poll interval plus the answer's time), `vehicles_lost` the vehicles
    retired for stale data over it."""
    import time

    import trio

    from entitynet.server import ServerConfig, serve
    from proxies.replay_core import ReplayWorld
    from proxies.replay_http import ReplayConfig, ReplayService, wall_service_clock
    from proxies.shell import ProxyConfig, ProxyShell
    from proxies.siri_client import StopMonitoringClient
    from proxies.siri_xml import ServiceClock

    out: dict = {}

    async def main():
        world = ReplayWorld(book.schedule, granularity=60.0, seed=3)
        service = ReplayService(world, ServiceClock.for_date(book.schedule.service_date),
                                wall_service_clock(8 * 3600.0 + 300.0), ReplayConfig(port=0))
        async with trio.open_nursery() as n:
            server = await n.start(serve, ServerConfig(port=0, digest=topo.digest, n_cells=topo.n_cells,
                                                       open_mode=True))
            await n.start(service.serve)
            shell = ProxyShell(topo, book, ProxyConfig(("127.0.0.1", server.port), poll=poll, timeout=5.0))
            client = StopMonitoringClient(f"http://127.0.0.1:{service.port}/siri", timeout=5.0)
            await n.start(shell.run, shell.siri_poller(client))
            with trio.fail_after(120.0):
                while shell.good_polls < 2 or not shell.fleet.vehicles:
                    await trio.sleep(0.1)
            before = len(shell.fleet.vehicles)
            progress(f"{before} vehicles on the map; tracker down for {outage:.0f} s")
            service.state.outage_until = time.monotonic() + outage
            await trio.sleep(outage)
            end, good = time.monotonic(), shell.good_polls
            with trio.fail_after(outage + 10.0 * poll + 60.0):
                while shell.good_polls == good:
                    await trio.sleep(0.02)
            out["recovery_s"] = time.monotonic() - end
            out["vehicles_lost"] = shell.fleet.counters.retired_stale
            out["vehicles_before_outage"] = before
            out["errors_counted"] = shell.metrics.value("entitynet_proxy_errors_total", kind="http_5xx")
            n.cancel_scope.cancel()

    trio.run(main)
    return out


def run(args, progress) -> dict:
    """The `entitynet bench proxy` suite: error per poll and ETA granularity, updates and CPU per vehicle,
    and recovery from an outage (virtual time, then real HTTP), as the report's body."""
    from proxies.replay_core import ReplayWorld
    from proxies.routes import build_routes
    from proxies.sim import run_sim

    feed = find_feed()
    if getattr(args, "topology", None):
        from topology.artifact import load

        topo = load(args.topology)
    else:
        from entitynet.topology_cache import bundled_topology

        topo, _ = bundled_topology(progress, with_pvs=False)
    quick = bool(getattr(args, "quick", False))
    duration = 600.0 if quick else 3600.0
    start = 8 * 3600.0
    latency = 3.0
    progress(f"routes of {feed.name} over the map")
    book = build_routes(topo, feed)
    progress(f"{len(book.routes)} trips, {len(book.stops)} stops")
    results: dict = {"position_error_m": {}}
    polls = (20.0,) if quick else (10.0, 20.0, 60.0)
    main = None
    for g in (60.0, 1.0):
        world = ReplayWorld(book.schedule, granularity=g, seed=1)
        for poll in polls:
            progress(f"poll {poll:.0f} s, ETA granularity {g:.0f} s, {duration:.0f} s of service")
            res, fleet = run_sim(topo, book, world, start=start, duration=duration, poll=poll, latency=latency)
            s = res.summary()
            results["position_error_m"][f"poll_{poll:.0f}s_eta_{g:.0f}s"] = s["position_error_m"]
            if g == 60.0 and poll == 20.0:
                main = (res, fleet, s)
    res, fleet, s = main
    progress(f"poll 20 s, ETA granularity 60 s with VehicleLocation, {duration:.0f} s of service")
    world = ReplayWorld(book.schedule, granularity=60.0, seed=1, locations=True)
    res_loc, _ = run_sim(topo, book, world, start=start, duration=duration, poll=20.0, latency=latency)
    results["position_error_m"]["poll_20s_eta_60s_with_location"] = res_loc.summary()["position_error_m"]
    results["vehicles_traced"] = s["vehicles_traced"]
    results["discarded_fraction"] = fleet.counters.discarded_fraction
    results["updates_per_vehicle_min"] = s["updates_per_vehicle_min"]
    results["proxy_cpu_s_per_vehicle_hour"] = s["proxy_cpu_s_per_vehicle_hour"]
    results["core_fraction_for_2000_vehicles"] = s["proxy_cpu_s_per_vehicle_hour"] * 2000.0 / 3600.0
    # a 2-minute outage of the tracker, 20 s polls, minute ETAs
    world = ReplayWorld(book.schedule, granularity=60.0, seed=2)
    out_from = 300.0 if quick else 900.0
    outage = (out_from, out_from + 120.0)
    progress("a 2-minute outage (virtual time)")
    res, fleet = run_sim(topo, book, world, start=start, duration=out_from + 420.0, poll=20.0, latency=latency,
                         outage=outage)
    results["error_recovery_s"] = recovery(res.series, outage, 120.0)
    results["vehicles_lost_virtual"] = res.lost
    http_outage, http_poll = (10.0, 2.0) if quick else (120.0, 20.0)
    progress(f"real HTTP: a {http_outage:.0f} s outage at {http_poll:.0f} s polls")
    real = measure_recovery(topo, book, outage=http_outage, poll=http_poll, progress=progress)
    results["recovery_s"] = real["recovery_s"]
    results["vehicles_lost"] = max(real["vehicles_lost"], res.lost)
    results["http_outage"] = {"outage_s": http_outage, "poll_s": http_poll, **real}
    params = {"feed": feed.name, "start": "08:00:00", "duration_s": duration, "latency_s": latency,
              "polls_s": list(polls), "eta_granularity_s": [60.0, 1.0], "outage_s": list(outage),
              "fleet": {"fix_interval_s": 2.0, "threshold_m": 8.0, "stale_after_s": 300.0}, "preview_s": 300.0}
    notes = ("virtual time; CPU = process time of the proxy's own work; error = distance between the published "
             "model extrapolated (what a viewer sees) and the replay's true position, every second per vehicle")
    return {"params": params, "results": results, "notes": notes}


def write_plot(report: dict, path: str) -> None:
    """docs/proxy.png: mean and p95 position error against the poll interval, for both ETA granularities."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    errs = report["results"]["position_error_m"]
    fig, ax = plt.subplots(figsize=(6.0, 3.6), dpi=110)
    for g, colour in (("60s", "tab:red"), ("1s", "tab:blue")):
        pts = sorted((float(k.split("_")[1][:-1]), v) for k, v in errs.items() if k.endswith("_eta_" + g))
        if not pts:
            continue
        xs = [p for p, _ in pts]
        ax.plot(xs, [v["p95"] for _, v in pts], "o-", color=colour, label=f"p95, ETAs to {g}")
        ax.plot(xs, [v["mean"] for _, v in pts], "s--", color=colour, alpha=0.6, label=f"mean, ETAs to {g}")
    ax.axhline(30.0, color="grey", lw=0.8, ls=":", label="target p95 (20 s poll, 1 min ETAs)")
    ax.set_xlabel("poll interval (s)")
    ax.set_ylabel("position error (m)")
    ax.set_title("SIRI proxy: where viewers see vehicles vs the truth")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
