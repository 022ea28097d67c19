"""`entitynet bench switch`: the shard server (a real subprocess) against Redis pub/sub and NATS, the same load
generator, at the standard load and on a saturation ladder.

Workload on the bundled map (or --topology): N publishing entities (`sims.mobility.Walkers`: 70 % pedestrians
at 1.4 m/s, 30 % cars at 8 m/s) walk the street network; like the client core, each sends an update when its
cell-occupation validity runs out (it reaches the next cell breakpoint) and otherwise every 5-15 s; cars longer
than a breakpoint occupy two cells. They are multiplexed over a few publisher connections (one frame per
connection per 5 ms tick).
V viewers subscribe to the PVS of a view cell over a random street node (half at street level, half above the
roofs); an artifact without a PVS falls back to the cells within 500 m, and the report's notes say so.

Redis run: the same entities and ticks, PUBLISH to one channel per occupied cell (pipelined); each viewer is a
connection SUBSCRIBEd to its cells' channels. NATS run: the same with one subject per cell (PUB / SUB,
`sims.bench.switch_drivers`). A delivery is counted once per (viewer, entity, seq): a Redis or NATS viewer
subscribed to both cells of a two-cell entity gets the message twice but it counts once. Latency is receive
time minus the publisher's send time written in the payload (same host clock).

The standard load is the first step of the ladder (`sims.bench.switch_ladder`); the existing result keys are
its figures. Server-side figures come from the server's Prometheus endpoint and psutil on the server process
(CPU over the measurement window; RSS growth from "viewers subscribed, no entities" to "all entities
published"). Servers are pinned to a core of their own when the machine has cores to spare
(`sims.bench.switch_systems.pin_plan`); the report says whether they were.
"""

from __future__ import annotations

import json
import math
import os
import random
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from entitynet.server import flushloop
from entitynet.switchboard.outbox import compiled_in_use
from sims.bench.switch_drivers import PAD, PAYLOAD, TICK, NatsDriver, OursDriver, RedisDriver
from sims.bench.switch_ladder import (
    DOWN_STEPS,
    FULL_STEPS,
    QUICK_STEPS,
    REFINE_ROUNDS,
    OfferedCounter,
    capacity,
    past_saturation,
    qualifies,
    ratio,
    refinements,
    step_row,
)
from sims.bench.switch_readers import LAT_BINS, ReaderLoop, Tally, reader_process
from sims.bench.switch_systems import (
    SYSTEMS,
    find_exe,
    pin_loadgen,
    pin_plan,
    started,
    usable_cores,
    workload_params,
)
from sims.mobility import Walkers

__all__ = ["PAD", "PAYLOAD", "TICK", "NatsDriver", "OursDriver", "RedisDriver", "run"]  # drivers re-exported

# ---------------------------------------------------------------------------------------------- workload
def pvs_viewer_cells(topo, n: int, rng: random.Random) -> list[tuple[int, ...]] | None:
    """Cells in the PVS of the view cell of a random street node, half at street level and half above the roofs
    (None when the artifact has no PVS)."""
    try:
        from topology.pvs_index import PvsIndex

        index = PvsIndex.from_topology(topo)
    except Exception as exc:  # no PVS, or one this version of topology.pvs cannot read: fall back, say so
        print(f"[bench] no usable PVS in the artifact ({type(exc).__name__}: {exc})", file=sys.stderr)
        return None
    top = float(topo.meta["pvs"].get("max_height", 40.0))
    out = []
    for k in range(n):
        x, y = topo.node_xy[rng.randrange(len(topo.node_xy))]
        z = 1.7 if k % 2 == 0 else min(40.0, max(1.7, top - 1.0))  # street level, or just above the roofs
        cells = tuple(int(c) for c in index.cells_at(float(x), float(y), z))
        out.append(cells or (0,))
    return out


def viewer_cells(topo, n: int, radius: float, rng: random.Random) -> list[tuple[int, ...]]:
    """Cells whose footprint is within `radius` of a random street node, per viewer."""
    import shapely

    polys = topo.cell_footprints.to_shapely()
    out = []
    for _ in range(n):
        x, y = topo.node_xy[rng.randrange(len(topo.node_xy))]
        d = shapely.distance(polys, shapely.Point(float(x), float(y)))
        out.append(tuple(int(c) for c in np.flatnonzero(d <= radius)))
    return out


# ---------------------------------------------------------------------------------------------- one run
def _run_load(driver, proc, walkers_factory, view_cells, p, progress, scrape=None, offered=None) -> dict[str, Any]:
    """One system at one offered load: viewers subscribe, publishers send for warm-up and window, the readers
    tally; `offered(cells)` counts the viewers an update reaches (the ideal deliveries)."""
    import multiprocessing as mp

    import psutil

    ps = psutil.Process(proc.pid)
    rss_empty = ps.memory_info().rss
    ctx = mp.get_context("fork")
    ready_v, w0, w1, stop = ctx.Value("i", 0), ctx.Value("d", math.inf), ctx.Value("d", math.inf), ctx.Value("b", 0)
    n_readers = p["reader_processes"]
    readers = []
    for r in range(n_readers):
        a, b = ctx.Pipe(duplex=False)
        share = view_cells[r::n_readers]
        pr = ctx.Process(target=reader_process, args=(driver, share, p["entities"], (ready_v, w0, w1, stop), b),
                         daemon=True)
        pr.start()
        readers.append((pr, a))
    replies = ReaderLoop(None)  # publishers' replies (WELCOME, Redis integer replies) are read and dropped
    rthread = threading.Thread(target=replies.run, daemon=True)
    pubs: list[socket.socket] = []
    try:
        deadline = time.time() + 180
        while ready_v.value < len(view_cells):
            if time.time() > deadline or any(not pr.is_alive() for pr, _ in readers):
                raise RuntimeError(f"{driver.name}: only {ready_v.value}/{len(view_cells)} viewers subscribed")
            time.sleep(0.05)
        time.sleep(0.5)
        rss_viewers = ps.memory_info().rss
        progress(f"{driver.name}: {len(view_cells)} viewers subscribed")
        for _ in range(p["publisher_connections"]):
            s = socket.create_connection(("127.0.0.1", driver.port))
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # no Nagle delay on small batches
            s.sendall(driver.publisher_hello())
            replies.add(socket.socket(fileno=os.dup(s.fileno())), lambda data, t: None)
            pubs.append(s)
        rthread.start()
        walkers = walkers_factory()
        sent = msgs_out = ideal = 0
        counting = False

        def send(items, now):
            nonlocal sent, msgs_out, ideal
            groups: list[list] = [[] for _ in pubs]
            for i, cells, val in items:
                groups[i % len(pubs)].append((i, walkers.seq[i], cells, val))
                if counting:
                    ideal += offered(cells)
            for s, g in zip(pubs, groups, strict=True):
                if g:
                    s.sendall(driver.publish_bytes(g, now))
            sent += len(items)
            msgs_out += sum(len(c) for _, c, _ in items)

        t0 = time.time()
        send(walkers.start(t0), t0)
        warm_end = t0 + p["warmup_s"]
        end = warm_end + p["window_s"]
        w0.value, w1.value = warm_end, end
        measured = False
        next_tick = time.monotonic()
        late = 0.0
        cpu_gen0 = time.process_time()
        while True:
            now = time.time()
            if not measured and now >= warm_end:
                measured = True
                rss_loaded = ps.memory_info().rss
                cpu0 = sum(ps.cpu_times()[:2])
                busy0 = _machine_busy(psutil)
                sent0, msgs0, wall0 = sent, msgs_out, now
                counting = offered is not None
                srv0 = _scrape_or_none(scrape, progress)
                progress(f"{driver.name}: measuring for {p['window_s']} s")
            if now >= end:
                counting = False
                wall = now - wall0
                cpu = sum(ps.cpu_times()[:2]) - cpu0
                busy = _machine_busy(psutil) - busy0
                srv1 = _scrape_or_none(scrape, progress)
                break
            send(walkers.due(now), now)
            next_tick += TICK
            delay = next_tick - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                late = max(late, -delay)
        time.sleep(0.5)  # let the last deliveries of the window arrive
        cpu_gen = time.process_time() - cpu_gen0
    finally:
        stop.value = 1
        replies.stop = True
        for s in pubs:
            s.close()
    count = dups = 0
    hist = np.zeros(LAT_BINS, dtype=np.int64)
    reader_cpu = 0.0
    for pr, pipe in readers:
        c, d, h, cpu_r = pipe.recv()
        count, dups, hist, reader_cpu = count + c, dups + d, hist + h, reader_cpu + cpu_r
        pr.join(10)
    tally = Tally(1, 1)
    tally.hist = hist
    res = {
        "updates_in_per_s": (sent - sent0) / wall,
        "publish_messages_per_s": (msgs_out - msgs0) / wall,
        "deliveries_per_s": count / wall,
        "offered_deliveries_per_s": ideal / wall if offered is not None else None,
        "duplicates_per_s": dups / wall,
        "latency_p50_ms": tally.quantile(0.5),
        "latency_p99_ms": tally.quantile(0.99),
        "server_cpu_s": cpu,
        "server_cpu_cores": cpu / wall,
        "machine_busy_cores": busy / wall,  # every process on the machine: others' load shows here
        "cpu_s_per_million_deliveries": cpu / max(count / 1e6, 1e-9),
        "rss_bytes_per_entity": (rss_loaded - rss_viewers) / len(walkers.seq),
        # the viewers' subscriptions: RSS growth from the empty server to all viewers subscribed, per cell held
        "rss_bytes_per_subscription": (rss_viewers - rss_empty) / max(sum(map(len, view_cells)), 1),
        "rss_empty_bytes": rss_empty,
        "rss_loaded_bytes": rss_loaded,
        "loadgen_max_tick_lateness_ms": late * 1000.0,
        "loadgen_publisher_cpu_s": cpu_gen,
        "loadgen_reader_cpu_s_total": reader_cpu,
    }
    if srv0 and srv1:
        for key, name in (("entitynet_updates_in_total", "server_updates_in_per_s"),
                          ("entitynet_deliveries_total", "server_messages_out_per_s"),
                          ("entitynet_frames_out_total", "server_frames_out_per_s")):
            res[name] = (srv1[key] - srv0[key]) / wall
        res.update(queue_latency(srv0, srv1))
    return res


QUEUE_BUCKET = 'entitynet_queue_latency_seconds_bucket{le="'


def queue_latency(srv0: dict[str, float], srv1: dict[str, float]) -> dict[str, float | None]:
    """Our server's own share of a delivery's latency over the window (from its outbox becoming non-empty to the
    batch written; a sample every 64 frames), from two scrapes of its histogram: the p50 and p99 as the upper
    bound of the bucket that holds them (None past the last finite bound, or with no sample). Why: the readers'
    latency is the server's plus the loopback and the load generator's reading; this says which part is ours."""
    buckets = sorted((float(k[len(QUEUE_BUCKET):-2]), srv1[k] - srv0.get(k, 0.0)) for k in srv1
                     if k.startswith(QUEUE_BUCKET))  # cumulative counts by upper bound, +Inf last
    total = buckets[-1][1] if buckets else 0.0
    out: dict[str, float | None] = {"server_queue_latency_samples": total}
    for q, name in ((0.5, "server_queue_latency_p50_le_ms"), (0.99, "server_queue_latency_p99_le_ms")):
        bound = next((b for b, c in buckets if total > 0 and c >= q * total), None)
        out[name] = bound * 1000.0 if bound is not None and bound != float("inf") else None
    return out


def _topology_path(args, progress, quick: bool) -> str:
    """--topology, else the cached bundled artifact (with PVS for the full run; the quick run takes the PVS
    one only if it is already cached, since building the PVS alone takes about a minute)."""
    if getattr(args, "topology", None):
        return str(args.topology)
    from entitynet.topology_cache import bundled_artifact_path, bundled_topology

    with_pvs = not quick or bundled_artifact_path(True).exists()
    _, path = bundled_topology(progress, with_pvs=with_pvs)
    return str(path)


def _machine_busy(psutil) -> float:
    """CPU seconds the whole machine has been busy (all processes, all cores) since boot."""
    t = psutil.cpu_times()
    return t.user + t.system + getattr(t, "nice", 0.0) + getattr(t, "irq", 0.0) + getattr(t, "softirq", 0.0)


def _scrape_or_none(scrape, progress) -> dict[str, float] | None:
    """The server's metrics, or None (and a word why) when a busy server does not answer in time: its own
    counters are extra figures, the load generator's tally is the measurement."""
    if scrape is None:
        return None
    try:
        return scrape()
    except OSError as exc:
        progress(f"metrics scrape failed ({exc}); the server-side counters are left out")
        return None


def _view_cells(topo, n: int, p: dict, notes: list[str], progress) -> list[tuple[int, ...]]:
    """The viewers' subscriptions: the PVS of street-node view cells, else the cells within `radius_m`. Both
    draw viewer by viewer from one seeded stream, so the first n of a larger set are the set for n."""
    view_cells = pvs_viewer_cells(topo, n, random.Random(p["seed"]))
    if view_cells is not None:
        p["subscription"] = "pvs"
        progress(f"viewer subscriptions: PVS of {n} street-node view cells (half above the roofs)")
        return view_cells
    p["subscription"] = f"radius {p['radius_m']:.0f} m"
    progress(f"viewer subscriptions: cells within {p['radius_m']:.0f} m of {n} street nodes")
    notes.append("the artifact has no PVS: viewers subscribe to the cells within 500 m of a random street "
                 "node, which is denser than PVS subscriptions")
    return viewer_cells(topo, n, p["radius_m"], random.Random(p["seed"]))


def _results(standard: dict[str, dict], ladder: dict[str, list], p: dict) -> dict[str, Any]:
    """The report's `results`: the standard load's figures of ours (the existing keys), the peers' deliveries,
    and per system the ladder's capacity and maximum with the capacity ratios."""
    ours = standard.get("entitynet")
    if ours is None:  # the notes say why; the peers' figures are still worth reporting
        ours = {k: None for k in ("updates_in_per_s", "deliveries_per_s", "latency_p50_ms", "latency_p99_ms",
                                  "cpu_s_per_million_deliveries", "rss_bytes_per_entity")}
    results = {k: ours[k] for k in ("updates_in_per_s", "deliveries_per_s", "latency_p50_ms", "latency_p99_ms",
                                    "cpu_s_per_million_deliveries", "rss_bytes_per_entity")}
    results.update({k: v for k, v in ours.items() if k not in results})
    for peer in ("redis", "nats"):
        res = standard.get(peer)
        results[f"{peer}_deliveries_per_s"] = res["deliveries_per_s"] if res else None
        results[f"{peer}_latency_p99_ms"] = res["latency_p99_ms"] if res else None
        results[f"ratio_vs_{peer}"] = ratio(ours["deliveries_per_s"], res["deliveries_per_s"] if res else None)
    caps = {system: capacity(rows) for system, rows in ladder.items()}
    for system, cap in caps.items():
        prefix = "" if system == "entitynet" else f"{system}_"
        results[f"{prefix}capacity_deliveries_per_s"] = cap["capacity_deliveries_per_s"]
        results[f"{prefix}max_deliveries_per_s"] = cap["max_deliveries_per_s"]
    mine = caps.get("entitynet", {}).get("capacity_deliveries_per_s")
    for peer in ("redis", "nats"):
        results[f"capacity_ratio_vs_{peer}"] = ratio(mine, caps.get(peer, {}).get("capacity_deliveries_per_s"))
        results[f"max_ratio_vs_{peer}"] = ratio(caps.get("entitynet", {}).get("max_deliveries_per_s"),
                                                caps.get(peer, {}).get("max_deliveries_per_s"))
    results["pinned"] = p["pinned"]
    return results


def run(args, progress) -> dict[str, Any]:
    """The suite: our server, Redis and NATS with the same viewers and walkers, step by step up the ladder
    (each step runs the three systems one after the other, so that drift in the machine's load hits all
    three); a system leaves the ladder once it is past saturation. The report body."""
    from topology.artifact import load

    quick = bool(getattr(args, "quick", False))
    steps = QUICK_STEPS if quick else FULL_STEPS
    cores = usable_cores()
    plan = pin_plan(cores)
    p = {
        "entities": steps[0][0],
        "viewers": steps[0][1],
        "ladder_steps": [list(s) for s in steps],
        **workload_params(cores, plan),
        "warmup_s": 2.0 if quick else 5.0,
        "window_s": 5.0 if quick else 20.0,
        "ladder_warmup_s": 5.0,
        "ladder_window_s": 10.0,
        "refine_rounds": 0 if quick else REFINE_ROUNDS,
        "update_interval_s": [5.0, 15.0],
        "payload_bytes": PAYLOAD.size + len(PAD),
        "tick_ms": TICK * 1000,
        "usable_cores": len(cores),
        "pinned": plan["pinned"],
        "pin_note": plan["note"],
        # the server subprocess runs this interpreter and environment: the same fan-out loops
        "compiled_fanout": compiled_in_use(),
        "compiled_flush": flushloop.compiled_in_use(),
    }
    progress(plan["note"])
    notes: list[str] = [plan["note"]]
    exes: dict[str, str | None] = {"entitynet": sys.executable}
    for system, binary in (("redis", "redis-server"), ("nats", "nats-server")):
        exes[system], how = find_exe(binary, binary, progress)
        notes.append(f"{system}: {how}")
    unpin = pin_loadgen(plan)  # the readers (forked) inherit it
    standard: dict[str, dict] = {}
    ladder: dict[str, list] = {s: [] for s in SYSTEMS if exes[s]}
    try:
        with tempfile.TemporaryDirectory(prefix="switch-bench-") as tmpd:
            topo_path = _topology_path(args, progress, quick)
            topo = load(topo_path)
            p["topology_digest"] = topo.digest[:16]
            p["n_cells"] = int(topo.n_cells)
            all_cells = _view_cells(topo, max(v for _, v in steps), p, notes, progress)
            p["mean_cells_per_viewer"] = float(np.mean([len(c) for c in all_cells[: p["viewers"]]]))
            climbing = list(ladder)

            def step(system: str, n_ent: int, n_view: int, standard_step: bool) -> dict[str, Any] | None:
                """One system at one step (fresh server); its row, or None (and a note) when it failed."""
                view_cells = all_cells[:n_view]
                pk = dict(p, entities=n_ent, viewers=n_view)
                if not standard_step:
                    pk.update(warmup_s=p["ladder_warmup_s"], window_s=p["ladder_window_s"])

                def walkers_factory():
                    return Walkers(topo, n_ent, random.Random(p["seed"] + 1))

                progress(f"step {n_ent} entities x {n_view} viewers: {system}")
                try:
                    with started(system, exes[system], topo_path, topo.digest, p, plan, Path(tmpd),
                                 progress) as (driver, proc, scrape):
                        res = _run_load(driver, proc, walkers_factory, view_cells, pk, progress, scrape,
                                        OfferedCounter(view_cells, p["n_cells"]))
                except (RuntimeError, OSError) as exc:
                    progress(f"{system} at {n_ent} x {n_view} failed: {exc!r}")
                    notes.append(f"{system} at {n_ent} x {n_view} failed: {exc!r}")
                    return None
                if standard_step:
                    standard[system] = res
                row = step_row(n_ent, n_view, res)
                ladder[system].append(row)
                shown = ("offered_deliveries_per_s", "deliveries_per_s", "latency_p99_ms", "machine_busy_cores")
                progress(f"{system}: {json.dumps({x: row[x] for x in shown}, default=float)}")
                return row

            for k, (n_ent, n_view) in enumerate(steps):  # upward from the standard load
                for system in list(climbing):
                    row = step(system, n_ent, n_view, k == 0)
                    if row is None or past_saturation(row):
                        climbing.remove(system)
                    elif (row["loadgen_max_tick_lateness_ms"] or 0.0) > 2000.0:
                        notes.append(f"the load generator fell {row['loadgen_max_tick_lateness_ms']:.0f} ms "
                                     f"behind at {n_ent} x {n_view} ({system}): it, not {system}, is the limit "
                                     "there; the ladder stops climbing")
                        climbing = []
                        break
                if not climbing:
                    break
            if not quick:  # downward, for the systems that qualified nowhere above
                for n_ent, n_view in DOWN_STEPS:
                    for system in [s for s in ladder if not any(qualifies(r) for r in ladder[s])]:
                        step(system, n_ent, n_view, False)
                for _ in range(p["refine_rounds"]):  # bisect each system's bracket: capacities within 1.19x
                    for system, n_ent in refinements(ladder).items():
                        step(system, n_ent, p["viewers"], False)
            for rows in ladder.values():
                rows.sort(key=lambda r: (r["viewers"], r["entities"]))
    finally:
        unpin()
    results = _results(standard, ladder, p)
    body: dict[str, Any] = {"params": p, "results": results, "notes": notes, "ladder": ladder}
    peers = {s: standard[s] for s in ("redis", "nats") if s in standard}
    if peers:
        body["peer"] = peers
        body["ratio"] = {
            "deliveries_per_s": results["ratio_vs_redis"],
            "capacity_vs_redis": results["capacity_ratio_vs_redis"],
            "capacity_vs_nats": results["capacity_ratio_vs_nats"],
            "cpu_s_per_million_deliveries": ratio(results["cpu_s_per_million_deliveries"],
                                                  peers["redis"]["cpu_s_per_million_deliveries"])
            if "redis" in peers else None,
        }
    progress(json.dumps({k: results[k] for k in ("deliveries_per_s", "latency_p99_ms", "ratio_vs_redis",
                                                 "capacity_deliveries_per_s", "capacity_ratio_vs_redis",
                                                 "capacity_ratio_vs_nats")}, default=float))
    return body
