"""`entitynet bench switch`: the shard server (a real subprocess) against Redis pub/sub, same load generator.

Workload on the bundled map (or --topology): N publishing entities (`sims.mobility.Walkers`: 70 % pedestrians
at 1.4 m/s, 30 % cars at 8 m/s) walk the street network; like the client core, each sends an update when its
cell-occupation validity runs out (it reaches the next cell breakpoint) and otherwise every 5-15 s; cars longer
than a breakpoint occupy two cells. They are multiplexed over a few publisher connections (one frame per
connection per 5 ms tick).
V viewers subscribe to the PVS of a view cell over a random street node (half at street level, half above the
roofs); an artifact without a PVS falls back to the cells within 500 m, and the report's notes say so.

Redis run: the same entities and ticks, PUBLISH to one channel per occupied cell (pipelined); each viewer is a
connection SUBSCRIBEd to its cells' channels. A delivery is counted once per (viewer, entity, seq): a Redis
viewer subscribed to both cells of a two-cell entity gets the message twice but it counts once. Latency is
receive time minus the publisher's send time written in the payload (same host clock).

Server-side figures come from the server's Prometheus endpoint and psutil on the server process (CPU over the
measurement window; RSS growth from "viewers subscribed, no entities" to "all entities published").
"""

from __future__ import annotations

import json
import math
import os
import random
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from entitynet import protocol as P
from sims.bench.switch_readers import LAT_BINS, ReaderLoop, Ready, Tally, reader_process
from sims.mobility import Walkers

PAYLOAD = struct.Struct("<dII")  # send time, loadgen entity id, seq  (+ padding: a dead-reckoning model)
PAD = b"\x00" * 32
TICK = 0.005


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


# ---------------------------------------------------------------------------------------------- drivers
class OursDriver:
    """The load generator speaking entitynet's protocol: HELLO, SUBSCRIBE and PUBLISH frames, UPDATE heads."""

    name = "entitynet"
    # an UPDATE's payload: bin8 of 48 bytes (c4 30), our 16-byte head, 32 zero bytes, identity nil (c0)
    pattern = rb"\xc4\x30(.{16})\x00{32}\xc0"

    def __init__(self, port: int, digest: str):
        self.port, self.digest = port, digest

    def publisher_hello(self) -> bytes:
        """What a publisher connection sends first."""
        return P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "bench", self.digest)])

    def viewer_hello(self, cells) -> tuple[bytes, Ready]:
        """A viewer's opening bytes and the marker that says its subscription is in place."""
        data = P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "bench", self.digest), P.Subscribe(tuple(cells), ()),
                               P.Ping(1)])
        return data, Ready(P.encode_message(P.Pong(1, 0))[:3], 1)  # the PONG after the subscription

    def publish_bytes(self, batch, now: float) -> bytes:
        """One frame of PUBLISHes for (entity, seq, cells, validity_ms) items, stamped with `now`."""
        msgs = [msgpack.packb([P.PUBLISH, i, seq, cells, val, PAYLOAD.pack(now, i, seq) + PAD])
                for i, seq, cells, val in batch]
        return P.frame(P.payload_from_encoded(msgs))


def _resp(*args: bytes) -> bytes:
    out = [b"*%d\r\n" % len(args)]
    for a in args:
        out.append(b"$%d\r\n%s\r\n" % (len(a), a))
    return b"".join(out)


class RedisDriver:
    """The same load against Redis pub/sub: one channel per cell, PUBLISH to every occupied cell."""

    name = "redis"
    # a pub/sub message: ... $48 CRLF, our 16-byte head, 32 zero bytes, CRLF
    pattern = rb"\$48\r\n(.{16})\x00{32}\r\n"

    def __init__(self, port: int):
        self.port = port

    def publisher_hello(self) -> bytes:
        """Redis needs no handshake."""
        return b""

    def viewer_hello(self, cells) -> tuple[bytes, Ready]:
        """SUBSCRIBE to the cells' channels; ready when every channel is acknowledged."""
        return _resp(b"SUBSCRIBE", *[b"c%d" % c for c in cells]), Ready(b"$9\r\nsubscribe\r\n", len(cells))

    def publish_bytes(self, batch, now: float) -> bytes:
        """A pipeline of PUBLISH commands, one per occupied cell of each item."""
        out = []
        for i, seq, cells, _val in batch:
            payload = PAYLOAD.pack(now, i, seq) + PAD
            for c in cells:
                out.append(_resp(b"PUBLISH", b"c%d" % c, payload))
        return b"".join(out)


# ---------------------------------------------------------------------------------------------- one run
def _run_load(driver, proc, walkers_factory, view_cells, p, progress, scrape=None) -> dict[str, Any]:
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
        sent = msgs_out = 0

        def send(items, now):
            nonlocal sent, msgs_out
            groups: list[list] = [[] for _ in pubs]
            for i, cells, val in items:
                groups[i % len(pubs)].append((i, walkers.seq[i], cells, val))
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
                sent0, msgs0, wall0 = sent, msgs_out, now
                srv0 = scrape() if scrape else None
                progress(f"{driver.name}: measuring for {p['window_s']} s")
            if now >= end:
                wall = now - wall0
                cpu = sum(ps.cpu_times()[:2]) - cpu0
                srv1 = scrape() if scrape else None
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
        "duplicates_per_s": dups / wall,
        "latency_p50_ms": tally.quantile(0.5),
        "latency_p99_ms": tally.quantile(0.99),
        "server_cpu_s": cpu,
        "cpu_s_per_million_deliveries": cpu / max(count / 1e6, 1e-9),
        "rss_bytes_per_entity": (rss_loaded - rss_viewers) / len(walkers.seq),
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
    return res


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, proc, timeout: float = 30.0) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited with status {proc.returncode}")
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
            return
        except OSError:
            time.sleep(0.05)
    raise RuntimeError(f"nothing listening on port {port} after {timeout} s")


def _scraper(port: int):
    def scrape() -> dict[str, float]:
        text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode()
        out = {}
        for line in text.splitlines():
            if line and not line.startswith("#"):
                k, _, v = line.rpartition(" ")
                out[k] = float(v)
        return out

    return scrape


def _find_redis(progress) -> tuple[str | None, str]:
    exe = shutil.which("redis-server") or ("/usr/bin/redis-server" if os.path.exists("/usr/bin/redis-server")
                                           else None)
    if exe:
        return exe, f"found {exe}"
    progress("redis-server not found; trying apt-get install -y redis-server")
    try:
        r = subprocess.run(["apt-get", "install", "-y", "redis-server"], capture_output=True, text=True,
                           timeout=300)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"redis-server not found and apt-get failed: {exc}"
    exe = shutil.which("redis-server")
    if exe:
        return exe, "installed redis-server with apt-get"
    return None, f"redis-server not found; apt-get exited {r.returncode}: {r.stderr.strip()[-300:]}"


def _topology_path(args, progress, quick: bool) -> str:
    """--topology, else the cached bundled artifact (with PVS for the full run; the quick run takes the PVS
    one only if it is already cached, since building the PVS alone takes about a minute)."""
    if getattr(args, "topology", None):
        return str(args.topology)
    from entitynet.topology_cache import bundled_artifact_path, bundled_topology

    with_pvs = not quick or bundled_artifact_path(True).exists()
    _, path = bundled_topology(progress, with_pvs=with_pvs)
    return str(path)


def run(args, progress) -> dict[str, Any]:
    """The suite: our server, then Redis, with the same viewers and walkers; the report body."""
    from topology.artifact import load

    quick = bool(getattr(args, "quick", False))
    p = {
        "entities": 2000 if quick else 5000,
        "viewers": 300 if quick else 1000,
        "publisher_connections": 4,
        "reader_processes": 2,
        "radius_m": 500.0,
        "warmup_s": 3.0 if quick else 5.0,
        "window_s": 8.0 if quick else 20.0,
        "flush_ms": 10.0,
        "update_interval_s": [5.0, 15.0],
        "payload_bytes": PAYLOAD.size + len(PAD),
        "tick_ms": TICK * 1000,
        "seed": 7,
    }
    notes = []
    with tempfile.TemporaryDirectory(prefix="switch-bench-") as tmpd:
        tmp = Path(tmpd)
        topo_path = _topology_path(args, progress, quick)
        topo = load(topo_path)
        p["topology_digest"] = topo.digest[:16]
        p["n_cells"] = int(topo.n_cells)
        view_cells = pvs_viewer_cells(topo, p["viewers"], random.Random(p["seed"]))
        if view_cells is not None:
            p["subscription"] = "pvs"
            progress(f"viewer subscriptions: PVS of {p['viewers']} street-node view cells (half above the roofs)")
        else:
            p["subscription"] = f"radius {p['radius_m']:.0f} m"
            progress(f"viewer subscriptions: cells within {p['radius_m']:.0f} m of {p['viewers']} street nodes")
            view_cells = viewer_cells(topo, p["viewers"], p["radius_m"], random.Random(p["seed"]))
            notes.append("the artifact has no PVS: viewers subscribe to the cells within 500 m of a random street "
                         "node, which is denser than PVS subscriptions")
        p["mean_cells_per_viewer"] = float(np.mean([len(c) for c in view_cells]))

        def walkers_factory():
            return Walkers(topo, p["entities"], random.Random(p["seed"] + 1))

        # ---- ours
        port, mport = _free_port(), _free_port()
        prof = os.environ.get("ENTITYNET_BENCH_PROFILE")  # developer aid: profile the server process
        cmd = [sys.executable, *(["-m", "cProfile", "-o", prof] if prof else []), "-m", "entitynet.cli",
               "serve", "--topology", topo_path, "--port", str(port), "--metrics-port", str(mport), "--open",
               "--flush-ms", str(p["flush_ms"])]
        progress("starting the entitynet server: " + " ".join(cmd[1:]))
        log = open(tmp / "server.log", "w")
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=str(Path(__file__).parents[2]))
        try:
            _wait_port(port, proc)
            ours = _run_load(OursDriver(port, topo.digest), proc, walkers_factory, view_cells, p, progress,
                             _scraper(mport))
        finally:
            proc.send_signal(2)  # SIGINT: graceful shutdown (and a written profile)
            try:
                proc.wait(60 if prof else 10)
            except subprocess.TimeoutExpired:
                proc.kill()
            log.close()
        # ---- redis
        peer = None
        exe, how = _find_redis(progress)
        notes.append(f"redis: {how}")
        if exe:
            rport = _free_port()
            rproc = subprocess.Popen([exe, "--port", str(rport), "--save", "", "--appendonly", "no",
                                      "--client-output-buffer-limit", "pubsub 0 0 0", "--maxclients", "20000"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            try:
                _wait_port(rport, rproc)
                out = subprocess.run([exe, "--version"], capture_output=True, text=True).stdout.strip()
                p["redis_version"] = out
                peer = _run_load(RedisDriver(rport), rproc, walkers_factory, view_cells, p, progress)
            except (RuntimeError, OSError) as exc:
                notes.append(f"redis run failed: {exc}")
            finally:
                rproc.kill()  # no graceful stop needed (no persistence); it may be busy flushing backlogs
                rproc.wait(10)
    results = {k: ours[k] for k in ("updates_in_per_s", "deliveries_per_s", "latency_p50_ms", "latency_p99_ms",
                                    "cpu_s_per_million_deliveries", "rss_bytes_per_entity")}
    results.update({k: v for k, v in ours.items() if k not in results})
    body: dict[str, Any] = {"params": p, "results": results, "notes": notes}
    if peer:
        results["redis_deliveries_per_s"] = peer["deliveries_per_s"]
        results["ratio_vs_redis"] = ours["deliveries_per_s"] / max(peer["deliveries_per_s"], 1e-9)
        body["peer"] = {"redis": peer}
        body["ratio"] = {
            "deliveries_per_s": results["ratio_vs_redis"],
            "cpu_s_per_million_deliveries": ours["cpu_s_per_million_deliveries"]
            / max(peer["cpu_s_per_million_deliveries"], 1e-9),
        }
    else:
        results["redis_deliveries_per_s"] = None
        results["ratio_vs_redis"] = None
    progress(json.dumps({k: results[k] for k in ("deliveries_per_s", "latency_p99_ms", "ratio_vs_redis")},
                        default=float))
    return body
