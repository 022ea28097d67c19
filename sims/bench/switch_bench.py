"""`entitynet bench switch`: the shard server (a real subprocess) against Redis pub/sub, same load generator.

Workload on the bundled map (or --topology): N publishing entities (70 % pedestrians at 1.4 m/s, 30 % cars at
8 m/s) walk the street network; like the client core, each sends an update when its cell-occupation validity
runs out (it reaches the next cell breakpoint) and otherwise every 5-15 s; cars longer than a breakpoint occupy
two cells. They are multiplexed over a few publisher connections (one frame per connection per 5 ms tick).
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

import heapq
import json
import math
import os
import random
import re
import select
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

PAYLOAD = struct.Struct("<dII")  # send time, loadgen entity id, seq  (+ padding: a dead-reckoning model)
PAD = b"\x00" * 32
TICK = 0.005
LAT_BIN = 1e-4  # latency histogram: 0.1 ms bins up to 5 s ...
LAT_FINE = 50_000
LAT_COARSE = 0.01  # ... then 10 ms bins up to 120 s; the last bin holds everything slower
LAT_BINS = LAT_FINE + 11_501


# ---------------------------------------------------------------------------------------------- workload
class Walkers:
    """Entities moving on the street graph; `due(now)` yields (entity, cells, validity_ms) of updates."""

    def __init__(self, topo, n: int, rng: random.Random):
        self.topo = topo
        self.rng = rng
        self.length = topo.edge_length.astype(float)
        self.edge_nodes = topo.edge_nodes
        self.n = n
        usable = np.flatnonzero(self.length > 1.0)
        self.edge = [int(rng.choice(usable)) for _ in range(n)]
        self.off = [rng.uniform(0, self.length[e]) for e in self.edge]
        self.dir = [rng.choice((1, -1)) for _ in range(n)]
        self.car = [rng.random() < 0.3 for _ in range(n)]
        self.speed = [8.0 if c else 1.4 for c in self.car]
        self.seq = [0] * n
        self.t = [0.0] * n
        self.heap: list[tuple[float, int]] = []

    def start(self, now: float) -> list[tuple[int, tuple[int, ...], int]]:
        out = []
        for i in range(self.n):
            self.t[i] = now
            out.append(self._update(i, now))
        return out

    def due(self, now: float) -> list[tuple[int, tuple[int, ...], int]]:
        out = []
        heap = self.heap
        while heap and heap[0][0] <= now:
            _, i = heapq.heappop(heap)
            self._advance(i, now)
            out.append(self._update(i, now))
        return out

    def _advance(self, i: int, now: float) -> None:
        dist = self.speed[i] * max(0.0, now - self.t[i])
        self.t[i] = now
        e, s, d = self.edge[i], self.off[i] + self.dir[i] * dist, self.dir[i]
        for _ in range(100):
            L = self.length[e]
            if 0.0 <= s <= L:
                break
            over = s - L if s > L else -s
            node = int(self.edge_nodes[e][1] if s > L else self.edge_nodes[e][0])
            cand = [int(x) for x in self.topo.edges_of_node(node) if int(x) != e] or [e]
            e = self.rng.choice(cand)
            if int(self.edge_nodes[e][0]) == node:
                d, s = 1, min(over, self.length[e])
            else:
                d, s = -1, max(self.length[e] - over, 0.0)
        self.edge[i], self.off[i], self.dir[i] = e, min(max(s, 0.0), self.length[e]), d

    def _update(self, i: int, now: float) -> tuple[int, tuple[int, ...], int]:
        e, s, d = self.edge[i], self.off[i], self.dir[i]
        starts, cells = self.topo.cell_pieces(e)
        k = max(int(np.searchsorted(starts, s, side="right")) - 1, 0)
        occ = [int(cells[k])]
        if self.car[i]:
            aft = min(max(s - d * 4.5, 0.0), self.length[e])
            ka = max(int(np.searchsorted(starts, aft, side="right")) - 1, 0)
            if ka != k:
                occ.append(int(cells[ka]))
        # validity: until the front reaches the next breakpoint (or the edge end) in its direction
        if d > 0:
            nxt = float(starts[k + 1]) if k + 1 < len(starts) else self.length[e]
            gap = nxt - s
        else:
            gap = s - float(starts[k])
        validity = min(60.0, max(0.5, gap / self.speed[i]))
        refresh = self.rng.uniform(5.0, 15.0)
        heapq.heappush(self.heap, (now + min(validity, refresh), i))
        self.seq[i] += 1
        return i, tuple(dict.fromkeys(occ)), int(validity * 1000)


def pvs_viewer_cells(topo, n: int, rng: random.Random) -> list[tuple[int, ...]] | None:
    """Cells in the PVS of the view cell of a random street node, half at street level and half above the roofs
    (None when the artifact has no PVS)."""
    try:
        from topology.pvs import PvsIndex

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


# ---------------------------------------------------------------------------------------------- accounting
class Tally:
    """Useful deliveries (once per viewer, entity, seq) and a latency histogram, during the window only.

    Vectorised: the load generator counts several hundred thousand deliveries per second in one Python
    process, so reads only pull the 16-byte payload heads out with one regex scan (every payload ends in 32
    zero bytes and a fixed trailer), and every 10 ms the collected heads are deduplicated and binned in numpy.
    """

    REC = np.dtype([("t", "<f8"), ("e", "<u4"), ("s", "<u4")])

    def __init__(self, n_viewers: int, n_entities: int):
        self.last = np.zeros((n_viewers, n_entities), dtype=np.uint32)
        self.count = 0
        self.dups = 0
        self.hist = np.zeros(LAT_BINS, dtype=np.int64)
        self.window = (math.inf, math.inf)  # deliveries received in [start, end) are counted
        self.pending: list[tuple[int, list[bytes], float]] = []

    def add(self, v: int, heads: list[bytes], t_recv: float) -> None:
        self.pending.append((v, heads, t_recv))

    def flush(self) -> None:
        pending, self.pending = self.pending, []
        if not pending:
            return
        counts = np.array([len(h) for _, h, _ in pending])
        rec = np.frombuffer(b"".join(b"".join(h) for _, h, _ in pending), dtype=self.REC)
        v = np.repeat(np.array([x[0] for x in pending], dtype=np.int64), counts)
        t_recv = np.repeat(np.array([x[2] for x in pending]), counts)
        e = rec["e"].astype(np.int64)
        s = rec["s"].astype(np.int64)
        key = (v << 52) | (e << 32) | s
        _, first = np.unique(key, return_index=True)
        dups = len(rec) - len(first)
        first.sort()
        v, e, s, t_sent, t_recv = v[first], e[first], s[first], rec["t"][first], t_recv[first]
        new = s > self.last[v, e]
        np.maximum.at(self.last, (v, e), s.astype(np.uint32))
        n_new = int(new.sum())
        self.dups += dups + len(s) - n_new
        new &= (t_recv >= self.window[0]) & (t_recv < self.window[1])
        n_new = int(new.sum())
        if n_new:
            self.count += n_new
            lat = np.maximum(t_recv[new] - t_sent[new], 0.0)
            b = np.where(lat < LAT_FINE * LAT_BIN, lat / LAT_BIN,
                         LAT_FINE + (lat - LAT_FINE * LAT_BIN) / LAT_COARSE).astype(np.int64)
            np.clip(b, 0, LAT_BINS - 1, out=b)
            self.hist += np.bincount(b, minlength=LAT_BINS)

    def quantile(self, q: float) -> float | None:
        total = int(self.hist.sum())
        if not total:
            return None
        b = int(np.searchsorted(np.cumsum(self.hist), q * total))
        if b < LAT_FINE:
            return (b + 0.5) * LAT_BIN * 1000.0
        return (LAT_FINE * LAT_BIN + (b - LAT_FINE + 0.5) * LAT_COARSE) * 1000.0


class Scanner:
    """Pulls the 16-byte payload heads out of a byte stream, keeping an incomplete tail for the next read."""

    def __init__(self, pattern: bytes, keep: int = 128):
        self.re = re.compile(pattern, re.S)
        self.buf = b""
        self.keep = keep

    def feed(self, data: bytes) -> list[bytes]:
        buf = self.buf + data if self.buf else data
        heads = self.re.findall(buf)
        if heads:
            end = buf.rfind(heads[-1]) + 16 + 34  # past the last record (head, padding, trailer)
            rest = buf[end:]
        else:
            rest = buf
        self.buf = rest[-self.keep :] if len(rest) > self.keep else rest
        return heads


class Ready:
    """Counts a marker (subscription acknowledged) across reads until `need` have been seen."""

    def __init__(self, marker: bytes, need: int):
        self.marker, self.need, self.tail = marker, need, b""

    def feed(self, data: bytes) -> bool:
        buf = self.tail + data
        self.need -= buf.count(self.marker) - self.tail.count(self.marker)
        self.tail = buf[-len(self.marker) :]
        return self.need <= 0


# ---------------------------------------------------------------------------------------------- drivers
class OursDriver:
    name = "entitynet"
    # an UPDATE's payload: bin8 of 48 bytes (c4 30), our 16-byte head, 32 zero bytes, identity nil (c0)
    pattern = rb"\xc4\x30(.{16})\x00{32}\xc0"

    def __init__(self, port: int, digest: str):
        self.port, self.digest = port, digest

    def publisher_hello(self) -> bytes:
        return P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "bench", self.digest)])

    def viewer_hello(self, cells) -> tuple[bytes, Ready]:
        data = P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "bench", self.digest), P.Subscribe(tuple(cells), ()),
                               P.Ping(1)])
        return data, Ready(P.encode_message(P.Pong(1, 0))[:3], 1)  # the PONG after the subscription

    def publish_bytes(self, batch, now: float) -> bytes:
        msgs = [msgpack.packb([P.PUBLISH, i, seq, cells, val, PAYLOAD.pack(now, i, seq) + PAD])
                for i, seq, cells, val in batch]
        return P.frame(P.payload_from_encoded(msgs))


def _resp(*args: bytes) -> bytes:
    out = [b"*%d\r\n" % len(args)]
    for a in args:
        out.append(b"$%d\r\n%s\r\n" % (len(a), a))
    return b"".join(out)


class RedisDriver:
    name = "redis"
    # a pub/sub message: ... $48 CRLF, our 16-byte head, 32 zero bytes, CRLF
    pattern = rb"\$48\r\n(.{16})\x00{32}\r\n"

    def __init__(self, port: int):
        self.port = port

    def publisher_hello(self) -> bytes:
        return b""

    def viewer_hello(self, cells) -> tuple[bytes, Ready]:
        return _resp(b"SUBSCRIBE", *[b"c%d" % c for c in cells]), Ready(b"$9\r\nsubscribe\r\n", len(cells))

    def publish_bytes(self, batch, now: float) -> bytes:
        out = []
        for i, seq, cells, _val in batch:
            payload = PAYLOAD.pack(now, i, seq) + PAD
            for c in cells:
                out.append(_resp(b"PUBLISH", b"c%d" % c, payload))
        return b"".join(out)


# ---------------------------------------------------------------------------------------------- one run
class ReaderLoop:
    """Sockets in one epoll loop: a read costs one syscall and a regex scan, not a task switch."""

    def __init__(self, tally: Tally | None):
        self.ep = select.epoll()
        self.handlers: dict[int, Any] = {}
        self.socks: list[socket.socket] = []
        self.tally = tally
        self.ready = 0
        self.stop = False

    def add(self, sock: socket.socket, handler) -> None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.socks.append(sock)
        self.handlers[sock.fileno()] = handler
        self.ep.register(sock.fileno(), select.EPOLLIN)

    def viewer(self, v: int, pattern: bytes, ready: Ready):
        scan = Scanner(pattern)
        state = {"ready": False}

        def handle(data: bytes, t: float) -> None:
            if not state["ready"] and ready.feed(data):
                state["ready"] = True
                self.ready += 1
            heads = scan.feed(data)
            if heads:
                self.tally.add(v, heads, t)

        return handle

    def run(self, on_tick=None) -> None:
        next_flush = time.monotonic() + 0.01
        while not self.stop:
            events = self.ep.poll(0.005)
            t = time.time()
            for fd, _ in events:
                try:
                    data = os.read(fd, 262144)
                except BlockingIOError:
                    continue
                except OSError:
                    data = b""
                if not data:
                    self.ep.unregister(fd)
                    continue
                self.handlers[fd](data, t)
            if time.monotonic() >= next_flush:
                if self.tally is not None:
                    self.tally.flush()
                if on_tick is not None:
                    on_tick(self)
                next_flush = time.monotonic() + 0.01
        for s in self.socks:
            s.close()


def _reader_process(driver, viewers, n_entities: int, shared, pipe) -> None:
    """One load-generator reader process: connects its share of the viewers and tallies what they get."""
    ready_v, w0, w1, stop = shared
    tally = Tally(len(viewers), n_entities)
    loop = ReaderLoop(tally)
    for k, cells in enumerate(viewers):
        s = socket.create_connection(("127.0.0.1", driver.port))
        hello, ready = driver.viewer_hello(cells)
        s.sendall(hello)
        loop.add(s, loop.viewer(k, driver.pattern, ready))
    reported = 0

    def tick(lp: ReaderLoop) -> None:
        nonlocal reported
        if lp.ready > reported:
            with ready_v.get_lock():
                ready_v.value += lp.ready - reported
            reported = lp.ready
        tally.window = (w0.value, w1.value)
        lp.stop = bool(stop.value)

    loop.run(tick)
    tally.flush()
    pipe.send((tally.count, tally.dups, tally.hist, time.process_time()))
    pipe.close()


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
        pr = ctx.Process(target=_reader_process, args=(driver, share, p["entities"], (ready_v, w0, w1, stop), b),
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
