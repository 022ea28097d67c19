"""`entitynet bench cluster [--quick]`: the same movers and PVS viewers over one plain switchboard and over 1, 2
and 4 shards joined by NATS, all real processes on this machine (docs/scaling.md).

Results (per shard count, and the headline figures at the largest):
  `cross_shard_fraction`   NATS messages received by switchboards per delivery to a viewer
  `cpu_s_per_million_deliveries`   CPU of every switchboard and nats-server process over the window, beside the
                           single plain server's (`ratio`)
  `handover_gap_ms`        p99 at viewers, from the LEAVE of an entity's old id to the first UPDATE of its new
                           one when it crossed a region border (REDIRECT)
  `viewer_duplicates`      times a viewer held one entity under two ids (must be 0)
  `entities_lost`          entities a viewer should see but still does not one validity period after movement
                           stops (`settle_s`: how long until every viewer had them all)
  `failover_recovery_s`    a switchboard SIGKILLed: until every viewer sees exactly what it should again
  `nats_node_failover_s`   the NATS node every shard uses killed: until every shard's heartbeat shows it
                           reconnected
"""

from __future__ import annotations

import contextlib
import random
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import psutil
import trio

from entitynet.cluster.local import LocalShards
from entitynet.cluster.natsd import NatsCluster
from sims.bench.cluster_load import Load


def _cpu_each(pids: list[int]) -> dict[int, tuple[float, float]]:
    """(user, system) CPU seconds of each process still alive."""
    out = {}
    for pid in pids:
        try:
            t = psutil.Process(pid).cpu_times()
            out[pid] = (t.user, t.system)
        except psutil.Error:
            pass
    return out


def _cpu(pids: list[int]) -> float:
    return sum(u + s for u, s in _cpu_each(pids).values())


def _per_process(roles: list[str], pids: list[int], before: dict, after: dict, seconds: float) -> dict[str, Any]:
    """Each process's CPU over the window, in ms per second (user, system): where a cluster's CPU goes (a shard
    against the single server, the NATS nodes)."""
    out = {}
    for role, pid in zip(roles, pids, strict=True):
        if pid in before and pid in after:
            u, s = (after[pid][i] - before[pid][i] for i in (0, 1))
            ms = 1000 / seconds
            out[role] = {"cpu_ms_per_s": round((u + s) * ms, 1), "user_ms_per_s": round(u * ms, 1),
                         "system_ms_per_s": round(s * ms, 1)}
    return out


def _p99(xs: list[float]) -> float | None:
    if not xs:
        return None
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(0.99 * len(xs)))]


class _Beats:
    """The shards' heartbeat counts, as `cluster status` hears them."""

    def __init__(self) -> None:
        self.latest: dict[int, dict] = {}
        self.times: dict[int, float] = {}
        self.heard: dict[int, int] = {}  # shard -> heartbeats heard
        self.declared_dead: dict[int, float] = {}  # shard -> when a heartbeat first said it is dead

    def handler(self, subject: str, reply, data: bytes) -> None:
        import msgpack

        try:
            m = msgpack.unpackb(data, raw=False, strict_map_key=False)
            self.latest[int(m[1])] = dict(m[4])
            self.times[int(m[1])] = trio.current_time()
            self.heard[int(m[1])] = self.heard.get(int(m[1]), 0) + 1
            for d in m[5] if len(m) > 5 else ():
                self.declared_dead.setdefault(int(d), trio.current_time())
        except Exception:
            pass

    def total(self, key: str) -> int:
        return sum(int(c.get(key, 0)) for c in self.latest.values())


async def _drive(topo, regions, shards: LocalShards, nats: NatsCluster | None, p: dict, view_cells, adjacency,
                 start_cells, failover: bool, progress) -> dict[str, Any]:
    from entitynet.cluster.nats_client import NatsClient

    k = shards.k
    addrs = shards.addresses

    def owner(cell: int) -> str:
        return addrs[int(regions.cell_region[cell])] if regions is not None else addrs[0]

    def home_of(cells) -> str:
        if regions is None:
            return addrs[0]
        votes = [0] * k
        for c in cells:
            votes[int(regions.cell_region[c])] += 1
        return addrs[max(range(k), key=votes.__getitem__)]

    load = Load(topo.digest, addrs, owner, adjacency, start_cells, view_cells, [home_of(c) for c in view_cells],
                p, random.Random(p["seed"]))
    beats = _Beats()
    pids = [pr.pid for pr in shards.procs] + ([n.proc.pid for n in nats.nodes] if nats else [])
    roles = ([f"shard_{i}" for i in range(len(shards.procs))] if nats else ["server"]) + \
        ([f"nats_{i}" for i in range(len(nats.nodes))] if nats else [])
    out: dict[str, Any] = {}
    # the listener uses the last node: it survives the node kill
    listen = NatsClient(nats.nodes[-1].url, name="bench") if nats is not None else contextlib.nullcontext()
    async with listen as nc, trio.open_nursery() as nursery:
        if nc is not None:
            nc.subscribe("en.*.hb", beats.handler)
            with trio.move_on_after(10):  # every shard heard twice: each has heard the others (REDIRECT addresses)
                while any(beats.heard.get(s, 0) < 2 for s in range(k)):
                    await trio.sleep(0.02)
        await load.start(nursery)
        await trio.sleep(p["warmup_s"])
        d0, e0, n0, t0 = load.deliveries(), _cpu_each(pids), beats.total("nats_in"), time.perf_counter()
        await trio.sleep(p["window_s"])
        d1, e1, n1, t1 = load.deliveries(), _cpu_each(pids), beats.total("nats_in"), time.perf_counter()
        deliveries = d1 - d0
        cpu = sum(u + s for u, s in e1.values()) - sum(u + s for pid, (u, s) in e0.items() if pid in e1)
        out["deliveries_per_s"] = round(deliveries / (t1 - t0), 1)
        out["cpu_s_per_million_deliveries"] = round(cpu / max(deliveries, 1) * 1e6, 1)
        out["cpu_by_process"] = _per_process(roles, pids, e0, e1, t1 - t0)
        out["cross_shard_fraction"] = round((n1 - n0) / max(deliveries, 1), 4) if nats else 0.0
        out["redirects"] = sum(m.redirects for m in load.movers)
        load.moving = False
        t_stop = trio.current_time()
        with trio.move_on_after(p["validity_ms"] / 1000):  # lost = still missing a validity period later
            while True:
                await trio.sleep(0.1)
                missing, doubled = load.missing_and_doubled()
                if missing == 0 and trio.current_time() - t_stop > 1.0:
                    break
        out["settle_s"] = round(trio.current_time() - t_stop, 2)
        out["entities_lost"] = missing
        dups_settled = sum(v.duplicates for v in load.viewers)
        out["viewer_duplicates"] = dups_settled + doubled
        gaps = [g for v in load.viewers for g in v.gaps]
        out["handovers_seen"] = len(gaps)
        p99 = _p99(gaps)
        out["handover_gap_ms"] = None if p99 is None else round(p99 * 1000, 1)
        out["handover_gap_ms_median"] = None if not gaps else round(statistics.median(gaps) * 1000, 1)
        if failover and nats is not None:
            progress(f"{k} shards: killing NATS node 0 (every shard's first server)")
            before = {s: c.get("nats_reconnects", 0) for s, c in beats.latest.items()}
            t_kill = trio.current_time()
            nats.nodes[0].kill()
            with trio.move_on_after(15):
                while not all(beats.latest.get(s, {}).get("nats_reconnects", 0) > before.get(s, 0)
                              for s in range(k)):
                    await trio.sleep(0.02)
            out["nats_node_failover_s"] = round(trio.current_time() - t_kill, 3)
            await trio.sleep(1.0)
            out["viewer_duplicates_after_nats_failover"] = sum(v.duplicates for v in load.viewers) - dups_settled
            progress(f"{k} shards: SIGKILL of shard 1")
            t_kill = trio.current_time()
            shards.kill(1)
            killed = ("127.0.0.1", shards.ports[1])
            recovered = rehomed = None
            with trio.move_on_after(20):
                while True:  # its clients are home elsewhere, and every viewer sees exactly what it should
                    await trio.sleep(0.05)
                    missing, doubled = load.missing_and_doubled()
                    off = load.all_off(killed)
                    if off and rehomed is None:
                        rehomed = trio.current_time() - t_kill
                    if off and missing == 0 and doubled == 0:
                        recovered = trio.current_time() - t_kill
                        break
            out["failover_recovery_s"] = None if recovered is None else round(recovered, 3)
            # the timeline of that failover: a survivor's heartbeat says shard 1 is dead, every client it had is
            # welcomed elsewhere, every viewer consistent (the recovery above)
            dead_at = beats.declared_dead.get(1)
            out["failover_timeline_s"] = {
                "declared_dead": None if dead_at is None else round(dead_at - t_kill, 3),
                "clients_rehomed": None if rehomed is None else round(rehomed, 3),
                "viewers_consistent": out["failover_recovery_s"]}
            # from the NATS node's kill on (both failovers), as before; the NATS part alone above
            out["viewer_duplicates_after_failover"] = sum(v.duplicates for v in load.viewers) - dups_settled
        nursery.cancel_scope.cancel()
    return out


def _setup(name: str, k: int | None, topo, topo_path: str, p: dict, tmp: Path, progress,
           spawn_only: bool = False) -> tuple:
    """One run's processes: the region map, NATS (for shards) and the switchboards; `spawn_only` leaves the
    wait until they listen to `LocalShards.wait_ready` (so several runs can start together)."""
    from topology.regions import build_regions

    regions = nats = map_path = None
    extra = ["--dead-after", str(p["dead_after_s"])] if k else []
    if k:
        regions = build_regions(topo, k, borders=False)  # the shards need cell -> region only
        map_path = tmp / f"regions-{k}.json"
        regions.save(map_path)
        nodes = p["nats_nodes_at_largest"] if k == max(p["shards"]) else 1
        nats = NatsCluster(nodes, log_dir=tmp).start()
    log_dir = tmp / name
    log_dir.mkdir()
    shards = LocalShards(Path(topo_path), map_path, nats.urls if nats else None, k or 1, log_dir, extra=extra)
    progress(f"{name}: starting {k or 1} switchboard process(es)" + (f" and {len(nats.nodes)} NATS node(s)"
                                                                  if nats else ""))
    try:
        shards.spawn() if spawn_only else shards.start()
    except BaseException:
        _teardown((regions, nats, shards))
        raise
    return regions, nats, shards


def _teardown(setup: tuple, fast: bool = False) -> None:
    """Stop a run's processes: SIGTERM and a wait for each, or with `fast` (--quick, after its measurement)
    SIGKILL at once, which saves the shards' orderly goodbyes (about 0.5 s a run)."""
    _regions, nats, shards = setup
    if fast:
        for i in range(len(shards.procs)):
            shards.kill(i)
    else:
        shards.stop()
    if nats is not None:
        nats.stop()


def run(args, progress) -> dict[str, Any]:
    """The benchmark: the same load over one plain switchboard, then 1, 2 and 4 shards (a shard and a NATS node
    killed at the largest), each as real processes; returns parameters, per-run figures and the headline results."""
    from sims.bench.switch_bench import pvs_viewer_cells
    from topology.artifact import load
    from topology.regions import cell_adjacency

    quick = bool(getattr(args, "quick", False))
    p = {
        "entities": 100 if quick else 600, "viewers": 20 if quick else 120, "shards": [1, 2, 4],
        "warmup_s": 1.5 if quick else 4.0, "window_s": 3.0 if quick else 15.0, "publish_interval_s": 1.0,
        "move_every_s": 2.0, "validity_ms": 5000, "dead_after_s": 1.0, "failover_s": 2.0, "seed": 7,
        "nats_nodes_at_largest": 3,
    }  # fmt: skip
    if getattr(args, "topology", None):
        topo_path = str(args.topology)
    else:  # the PVS artifact even for --quick: viewers subscribe by PVS (built once, then cached)
        from entitynet.topology_cache import bundled_topology

        topo_path = str(bundled_topology(progress, with_pvs=True)[1])
    topo = load(topo_path)
    rng = random.Random(p["seed"])
    view_cells = pvs_viewer_cells(topo, p["viewers"], rng)
    notes = []
    if view_cells is None:
        raise SystemExit("the cluster benchmark needs an artifact with a PVS")
    adj = [sorted(a) for a in cell_adjacency(topo)]
    moving = [c for c in range(topo.n_cells) if adj[c]]
    start_cells = [rng.choice(moving) for _ in range(p["entities"])]
    p["topology_digest"] = topo.digest[:16]
    p["mean_cells_per_viewer"] = round(statistics.mean(len(c) for c in view_cells), 1)
    by_k: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="cluster-bench-") as tmpd:
        tmp = Path(tmpd)
        runs: list[tuple[str, int | None]] = [("single", None)] + [(f"shards_{k}", k) for k in p["shards"]]
        # --quick starts every run's processes at once, before any measurement (one after another, the
        # interpreters' start and the artifact's load were a third of its time); each run's own processes are
        # then the only busy ones in its window, the others idle (a heartbeat every 0.25 s). The full run
        # starts each run's processes just before it, as always.
        setups: dict[str, tuple] = {}
        try:
            if quick:
                for name, k in runs:
                    setups[name] = _setup(name, k, topo, topo_path, p, tmp, progress, spawn_only=True)
                for name, _k in runs:
                    setups[name][2].wait_ready(timeout=90.0)  # 8 interpreters at once on a few cores
            for name, k in runs:
                if name not in setups:
                    setups[name] = _setup(name, k, topo, topo_path, p, tmp, progress)
                regions, nats, shards = setups[name]
                try:
                    failover = k is not None and k == max(p["shards"]) and k > 1
                    res = trio.run(_drive, topo, regions, shards, nats, p, view_cells, adj, start_cells, failover,
                                   progress)
                finally:
                    _teardown(setups.pop(name), fast=quick)
                if regions is not None:
                    res["balance"] = regions.report["balance"]
                by_k[name] = res
                progress(f"{name}: {res}")
        finally:
            for setup in setups.values():
                _teardown(setup, fast=True)
    largest = by_k[f"shards_{max(p['shards'])}"]
    single = by_k["single"]
    results = {
        "cross_shard_fraction": largest["cross_shard_fraction"],
        "cpu_s_per_million_deliveries": largest["cpu_s_per_million_deliveries"],
        "handover_gap_ms": largest["handover_gap_ms"],
        "viewer_duplicates": sum(r["viewer_duplicates"] + r.get("viewer_duplicates_after_failover", 0)
                                 for r in by_k.values()),
        "entities_lost": sum(r["entities_lost"] for r in by_k.values()),
        "failover_recovery_s": largest.get("failover_recovery_s"),
        "nats_node_failover_s": largest.get("nats_node_failover_s"),
        "by_shards": by_k,
    }
    ratio = {"cpu_per_delivery_vs_single": round(largest["cpu_s_per_million_deliveries"]
                                                 / max(single["cpu_s_per_million_deliveries"], 1e-9), 3)}
    targets = {"cpu_ratio_max": 1.3, "cross_shard_fraction_max": 0.15, "failover_within_s": p["validity_ms"] / 1000}
    notes.append(f"targets: {targets}")
    return {"params": p, "results": results, "peer": {"single_server": single}, "ratio": ratio, "notes": notes}
