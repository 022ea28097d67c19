"""A local cluster for a simulation or the demo: `entitynet sim --shards K` and `entitynet demo --shards K`.

`local_cluster(...)` is an async context manager: it starts nats-server node(s) and K `entitynet serve --cluster`
processes on loopback (`entitynet.cluster.natsd`, `entitynet.cluster.local`), waits until every shard has
announced itself on NATS (so shards know each other's addresses before the first REDIRECT), yields a
`ClusterRun` with the shards' addresses and the region map, listens to the shards' heartbeats for per-shard
figures, and tears everything down when the block exits, however it exits (duration, Ctrl-C, an error).

Why processes and why the children are tied to this one: a shard is a process in production, and a demo that is
interrupted (or killed) must leave no nats-server or switchboard behind. The children run in their own session
(a terminal's Ctrl-C reaches only this process, which stops its clients first and then the shards, so the viewers
do not see the shards die under them) and with PR_SET_PDEATHSIG, so even a SIGKILL of this process takes them
along. They must therefore be started from the main thread, which is what this module does (synchronously,
before the simulation's clients exist).
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import trio

Say = Callable[[str], None]


def shard_locator(topo: Any, regions: Any) -> Callable[[float, float], int]:
    """A function from a local position to the shard whose region holds it: the view-grid column's region
    (`RegionMap.region_at`), or without a view grid the region of the nearest cell centre."""
    from topology.regions import cell_centres_and_areas

    centres, _areas = cell_centres_and_areas(topo)
    cell_region = np.asarray(regions.cell_region)

    def shard_at(x: float, y: float) -> int:
        r = regions.region_at(x, y)
        if r is not None:
            return int(r)
        return int(cell_region[int(np.argmin(np.hypot(centres[:, 0] - x, centres[:, 1] - y)))])

    return shard_at


@dataclass
class ClusterRun:
    """A running local cluster: where the shards listen, which region each owns, and what their heartbeats say."""

    regions: Any  # topology.regions.RegionMap
    addresses: list[tuple[str, int]]
    nats_urls: str
    shard_at: Callable[[float, float], int]
    pids: list[int] = field(default_factory=list)  # every child process (nats-server nodes and shards)
    beats: dict[int, dict] = field(default_factory=dict)  # shard -> its latest heartbeat counts
    first: dict[int, tuple[float, dict]] = field(default_factory=dict)  # shard -> (time, counts) of its first beat
    last_at: dict[int, float] = field(default_factory=dict)
    peaks: dict[int, dict] = field(default_factory=dict)  # shard -> the most clients / entities / mirrored seen
    _window: dict[int, tuple[float, int]] = field(default_factory=dict)

    def address_at(self, x: float, y: float) -> tuple[str, int]:
        """The address of the shard that owns the region at local (x, y)."""
        return self.addresses[self.shard_at(x, y)]

    def on_beat(self, subject: str, reply: str | None, data: bytes) -> None:
        """A heartbeat heard on NATS (anything unreadable on the subject is ignored)."""
        try:
            m = msgpack.unpackb(data, raw=False, strict_map_key=False)
            shard, counts = int(m[1]), dict(m[4])
        except Exception:  # not one of our heartbeats
            return
        now = trio.current_time()
        self.beats[shard] = counts
        self.last_at[shard] = now
        self.first.setdefault(shard, (now, counts))
        peak = self.peaks.setdefault(shard, {})
        mirrored = int(counts.get("mirrored", 0))
        for key, v in (("clients", int(counts.get("clients", 0))), ("mirrored", mirrored),
                       ("entities", int(counts.get("entities", 0)) - mirrored)):
            peak[key] = max(peak.get(key, 0), v)

    def per_shard(self) -> list[dict]:
        """One dict per shard from its latest heartbeat: clients, own entities, mirrored entities, subscribed
        cells, updates in and deliveries out (totals and rates since the shard's first heartbeat heard)."""
        out = []
        for s in range(len(self.addresses)):
            c = self.beats.get(s, {})
            t0, c0 = self.first.get(s, (0.0, {}))
            dt = self.last_at.get(s, 0.0) - t0
            mirrored = int(c.get("mirrored", 0))
            out.append({
                "shard": s, "address": "{}:{}".format(*self.addresses[s]), "heard": s in self.beats,
                "clients": int(c.get("clients", 0)), "entities": int(c.get("entities", 0)) - mirrored,
                "mirrored": mirrored, "subscriptions": int(c.get("subscriptions", 0)),
                "updates_in": int(c.get("updates_in", 0)), "deliveries": int(c.get("deliveries", 0)),
                "peak": dict(self.peaks.get(s, {})),
                "nats_in": int(c.get("nats_in", 0)), "nats_out": int(c.get("nats_out", 0)),
                "updates_per_s": round((c.get("updates_in", 0) - c0.get("updates_in", 0)) / dt, 1) if dt > 0 else 0.0,
                "deliveries_per_s": (round((c.get("deliveries", 0) - c0.get("deliveries", 0)) / dt, 1)
                                     if dt > 0 else 0.0),
            })
        return out

    def summary(self) -> str:
        """The per-shard part of the live summary line: own entities / mirrored, clients, deliveries per second
        since the previous summary."""
        now = trio.current_time()
        parts = []
        for s in self.per_shard():
            t0, d0 = self._window.get(s["shard"], (None, 0))
            rate = (s["deliveries"] - d0) / (now - t0) if t0 is not None and now > t0 else 0.0
            self._window[s["shard"]] = (now, s["deliveries"])
            parts.append(f"#{s['shard']} {s['entities']}+{s['mirrored']}m {s['clients']}c {rate:.0f}d/s")
        return "shards " + ", ".join(parts)


@contextlib.asynccontextmanager
async def local_cluster(topo: Any, artifact: Path, regions: Any, nats_nodes: int = 1, say: Say = print,
                        start_timeout: float = 60.0, extra: list[str] | None = None) -> AsyncIterator[ClusterRun]:
    """Start NATS and one `serve --cluster` process per region of `regions` on loopback, yield a `ClusterRun`,
    and stop everything on the way out (see the module docstring). Raises RuntimeError (with the log's path)
    when nats-server is missing or a process does not start; nothing is left running then either."""
    from entitynet.cluster.local import LocalShards
    from entitynet.cluster.nats_client import NatsClient
    from entitynet.cluster.natsd import NatsCluster, NatsServerMissing

    k = regions.shards
    run_dir = Path(tempfile.mkdtemp(prefix="entitynet-cluster-"))
    keep_logs = False
    try:
        map_path = run_dir / "regions.json"
        regions.save(map_path)
        nats = NatsCluster(nats_nodes, log_dir=run_dir, tie_to_parent=True)
        try:
            nats.start()
        except NatsServerMissing as exc:
            raise RuntimeError(str(exc)) from None
        try:
            shards = LocalShards(Path(artifact), map_path, nats.urls, k, run_dir, extra=list(extra or []),
                                 tie_to_parent=True)
            try:
                try:
                    shards.start(timeout=start_timeout)
                except RuntimeError:
                    keep_logs = True  # the error names a log in run_dir
                    raise
                run = ClusterRun(regions, [("127.0.0.1", p) for p in shards.ports], nats.urls,
                                 shard_locator(topo, regions),
                                 [n.proc.pid for n in nats.nodes] + [pr.pid for pr in shards.procs])
                say(f"cluster: NATS {nats.urls} ({nats_nodes} node{'s' if nats_nodes > 1 else ''}), {k} shards "
                    + ", ".join(f"#{i} {h}:{p}" for i, (h, p) in enumerate(run.addresses))
                    + f"; logs in {run_dir} (kept if the run fails)")
                async with NatsClient(nats.nodes[-1].url, name="entitynet-sim") as nc:
                    nc.subscribe(f"en.{regions.digest[:12]}.hb", run.on_beat)
                    with trio.move_on_after(start_timeout):
                        # every shard announced twice: each has then heard the others' first heartbeat
                        while not all(s in run.first and run.last_at[s] > run.first[s][0] for s in range(k)):
                            await trio.sleep(0.05)
                    missing = [s for s in range(k) if s not in run.beats]
                    if missing:
                        keep_logs = True
                        raise RuntimeError(f"shards {missing} never joined the cluster; see {run_dir}")
                    try:
                        yield run
                    except Exception:
                        keep_logs = True  # the shards' logs may say why
                        raise
            finally:
                shards.stop()
        finally:
            nats.stop()
    finally:
        if not keep_logs:
            shutil.rmtree(run_dir, ignore_errors=True)
