"""The switch benchmark's workload replayed through the `Switchboard` core: no sockets, simulated time.

Why: the switch benchmark measures a real server over real sockets, so its figures vary from run to run and
cannot show that a change left forwarding *behaviour* alone. This replay drives the sans-IO core with exactly
the same workload (the benchmark's viewers and movers, the same seeds and tick), on a simulated clock, and
digests everything the core hands to the shell: every frame (which client, in which flush), every UPDATE and
every LEAVE in it. Two runs with the same parameters give the same digest; a refactor of the mobility model,
the core or the codec that changes a single delivery, frame boundary or RNG draw changes it.

The shell's part is mimicked the way `entitynet.server.app` does it: publisher bytes are framed with the
benchmark's driver and decoded with the protocol codec, the switchboard is flushed every `flush_ms` (one frame
per client with news), and expiry runs when the core's next deadline has passed.

With `sockets=True` (`--sockets`) every client also gets a real loopback TCP connection and each flush goes
through the server's own flush loop (`entitynet.server.flushloop.flush_short`, compiled where built): one
frame and one `writev` per client with news. The digest is then taken from the bytes the peers *receive*, so
the pinned digest also proves that the socket path sends exactly what the core queued; `flush_s` is the CPU
time of those flushes (draining, framing and the system calls), robust to other load on the machine.

`python -m sims.bench.switch_replay [--topology FILE] [--entities N] [--viewers N] [--seconds S] [--sockets]`
prints the result as JSON.
"""

from __future__ import annotations

import hashlib
import random
import socket
import time
from dataclasses import asdict, dataclass, field

import msgpack

from entitynet import protocol as P
from entitynet.server.flushloop import FlushConn, flush_short
from entitynet.switchboard import Switchboard, SwitchConfig
from sims.bench.switch_bench import TICK, OursDriver, pvs_viewer_cells, viewer_cells
from sims.mobility import Walkers


@dataclass(frozen=True)
class ReplayResult:
    """What the core sent in a replay: counts, and digests over the bytes (hex sha256).

    `digest` covers the forwarding behaviour: per flush, per client, the frame's UPDATE and LEAVE messages.
    `control_digest` covers the rest (WELCOME, PONG, ERROR), kept apart so that a deliberate handshake change
    does not hide in the forwarding digest.
    """

    digest: str
    control_digest: str
    updates_in: int
    deliveries: int
    leaves: int
    frames: int
    control: int
    expired: int
    # CPU seconds spent inside the core's calls (receive, expire, take_dirty, draining the outboxes): timed, so
    # left out of comparisons; `core_us_per_delivery` is the pure forwarding cost the socket bench cannot separate
    core_s: float = field(default=0.0, compare=False)
    # with sockets: CPU seconds of the flushes through the server's flush loop (take, frame, writev), and frames
    flush_s: float = field(default=0.0, compare=False)
    # with `hold_below`: states that waited one more flush in a held small frame (each waited one `flush_ms` more)
    held_states: int = field(default=0, compare=False)

    @property
    def core_us_per_delivery(self) -> float:
        """Core time per delivered UPDATE in microseconds (reading, forwarding, draining; no sockets)."""
        return self.core_s * 1e6 / max(self.deliveries, 1)

    @property
    def flush_us_per_frame(self) -> float:
        """With sockets: CPU time of the flush loop per frame written, in microseconds."""
        return self.flush_s * 1e6 / max(self.frames, 1)

    @property
    def total_us_per_delivery(self) -> float:
        """Core and (with sockets) flush time per delivered UPDATE in microseconds."""
        return (self.core_s + self.flush_s) * 1e6 / max(self.deliveries, 1)


class _Wire:
    """Loopback TCP pairs, one per client: the server's end is written by `flush_short`, the peer's end is read
    back into frames of raw messages (each message's own bytes, as the core encoded them)."""

    def __init__(self) -> None:
        self.lst = socket.socket()
        self.lst.bind(("127.0.0.1", 0))
        self.lst.listen(64)
        self.srv: dict[int, socket.socket] = {}
        self.peer: dict[int, socket.socket] = {}
        self.dec: dict[int, P.FrameDecoder] = {}

    def open(self, cid: int) -> int:
        peer = socket.create_connection(self.lst.getsockname())
        srv, _ = self.lst.accept()
        srv.setblocking(False)
        peer.settimeout(10.0)
        self.srv[cid], self.peer[cid] = srv, peer
        self.dec[cid] = P.FrameDecoder(P.CodecLimits(max_frame=1 << 24, max_messages=1 << 20))
        return srv.fileno()

    def finish(self, conn: FlushConn) -> None:
        """What the writer task would do for a write the kernel took only in part: send the rest."""
        rest, conn.rest, conn.busy = conn.rest, None, False
        srv = self.srv[conn.cid]
        srv.setblocking(True)
        srv.settimeout(10.0)
        while rest:
            self.dec[conn.cid].receive_data(self.peer[conn.cid].recv(1 << 20))  # make room as a reader would
            try:
                n = srv.send(rest)
            except BlockingIOError:
                n = 0
            rest = rest[n:]
        srv.setblocking(False)

    def frame(self, cid: int) -> list[bytes]:
        """The next frame the peer of `cid` received, as the raw bytes of each message."""
        dec = self.dec[cid]
        while (payload := dec.next_payload()) is None:
            dec.receive_data(self.peer[cid].recv(1 << 20))
        unpacker = msgpack.Unpacker()
        unpacker.feed(payload)
        n = unpacker.read_array_header()
        out = []
        start = unpacker.tell()
        for _ in range(n):
            unpacker.skip()
            end = unpacker.tell()
            out.append(payload[start:end])
            start = end
        return out

    def close(self) -> None:
        for s in (*self.srv.values(), *self.peer.values(), self.lst):
            s.close()


def replay(topo, *, entities: int = 2000, viewers: int = 300, seconds: float = 11.0, seed: int = 7,
           publisher_connections: int = 4, flush_ms: float = 10.0, radius_m: float = 500.0,
           sockets: bool = False, hold_below: int = 0) -> ReplayResult:
    """Run the switch benchmark's workload through a fresh `Switchboard` for `seconds` of simulated time
    (with `sockets`, flushed through the server's flush loop onto loopback TCP; see the module docstring).
    `hold_below` (with `sockets`) is the server's `flush_min_frame`: fewer states than it wait one more flush,
    once (the digest then differs from the pinned one: frames move to later flushes).

    Seeds and derived streams are those of `sims.bench.switch_bench.run` (viewers from `seed`, movers from
    `seed + 1`); the simulated clock starts at 1000 s and advances by the benchmark's 5 ms tick.
    """
    view_cells = pvs_viewer_cells(topo, viewers, random.Random(seed)) if "pvs" in topo.meta else None
    if view_cells is None:
        view_cells = viewer_cells(topo, viewers, radius_m, random.Random(seed))
    t0 = 1000.0
    sb = Switchboard(SwitchConfig(n_cells=int(topo.n_cells), digest=topo.digest, open_mode=True, seed=seed), t0)
    driver = OursDriver(0, topo.digest)
    h_fwd, h_ctl = hashlib.sha256(), hashlib.sha256()
    counts = {"deliveries": 0, "leaves": 0, "frames": 0, "control": 0}
    clock = time.process_time  # CPU time of this process: preemption by other processes is not counted
    core = [0.0]
    flush_cpu = [0.0]
    held_states = [0]
    wire = _Wire() if sockets else None
    conns: dict[int, FlushConn] = {}
    codec = sb.config.codec
    max_body = codec.max_frame - 5
    sure_fit = max(1, max_body // (64 + codec.max_payload + 5 * codec.max_publish_cells + 4 * codec.max_str))

    def feed(cid: int, data: bytes, now: float) -> None:
        t = clock()
        dec = P.FrameDecoder()
        dec.receive_data(data)
        while (msgs := dec.next_messages()) is not None:
            sb.receive(cid, msgs, now)
        core[0] += clock() - t

    def flush(now: float) -> None:
        t = clock()
        dirty = sorted(sb.take_dirty())
        drained: dict[int, list[bytes]] = {}
        sent: set[int] = set()
        if wire is None:
            for cid in dirty:
                ob = sb.outbox(cid)
                if ob is not None and (msgs := ob.drain()):
                    b"".join(msgs)  # what a shell does with them (timed, as before)
                    drained[cid] = msgs
            core[0] += clock() - t
        else:
            core[0] += clock() - t
            t = clock()
            res = flush_short(dirty, conns, now, 20_000, sure_fit, max_body, 0, hold_below)
            slow, blocked, held = res[4], res[5], res[7]
            flush_cpu[0] += clock() - t
            if held:
                sb.mark_dirty(held)
                held_states[0] += sum(len(conns[cid].outbox) for cid in held)
            for conn in blocked:
                wire.finish(conn)
            sent = {cid for cid in dirty if cid in conns} - {c.cid for c in slow} - set(held)
            for conn in slow:  # replies (WELCOME) in front of states: drained, as the server's long path does
                if msgs := conn.outbox.drain():
                    drained[conn.cid] = msgs
        for cid in dirty:
            if cid in sent:
                msgs = wire.frame(cid)
            elif cid in drained:
                msgs = drained[cid]
            else:
                continue
            counts["frames"] += 1
            h_fwd.update(b"F%d:%d;" % (cid, len(msgs)))
            for enc in msgs:
                kind = msgpack.unpackb(enc, raw=False)[0]
                if kind == P.UPDATE:
                    counts["deliveries"] += 1
                    h_fwd.update(enc)
                elif kind == P.LEAVE:
                    counts["leaves"] += 1
                    h_fwd.update(enc)
                else:
                    counts["control"] += 1
                    h_ctl.update(b"C%d;" % cid + enc)

    def connect(peer: str) -> int:
        cid = sb.connect(t0, peer)
        if wire is not None:
            conns[cid] = FlushConn(cid, sb.outbox(cid), wire.open(cid))
        return cid

    for cells in view_cells:
        cid = connect("viewer")
        hello, _ready = driver.viewer_hello(cells)
        feed(cid, hello, t0)
    pubs = [connect("publisher") for _ in range(publisher_connections)]
    for cid in pubs:
        feed(cid, driver.publisher_hello(), t0)
    flush(t0)

    walkers = Walkers(topo, entities, random.Random(seed + 1))
    updates_in = 0
    expired = 0

    def send(items, now: float) -> None:
        nonlocal updates_in
        groups: list[list] = [[] for _ in pubs]
        for i, cells, val in items:
            groups[i % len(pubs)].append((i, walkers.seq[i], cells, val))
        for cid, g in zip(pubs, groups, strict=True):
            if g:
                feed(cid, driver.publish_bytes(g, now), now)
        updates_in += len(items)

    send(walkers.start(t0), t0)
    n_ticks = int(round(seconds / TICK))
    ticks_per_flush = max(1, int(round(flush_ms / 1000.0 / TICK)))
    for k in range(1, n_ticks + 1):
        now = t0 + k * TICK
        send(walkers.due(now), now)
        deadline = sb.next_deadline()
        if deadline is not None and deadline <= now:
            t = clock()
            expired += sb.expire(now)
            core[0] += clock() - t
        if k % ticks_per_flush == 0:
            flush(now)
    flush(t0 + n_ticks * TICK)
    if wire is not None:
        wire.close()
    return ReplayResult(h_fwd.hexdigest(), h_ctl.hexdigest(), updates_in, counts["deliveries"], counts["leaves"],
                        counts["frames"], counts["control"], expired, core[0], flush_cpu[0], held_states[0])


if __name__ == "__main__":  # pragma: no cover - a small report tool
    import argparse
    import json

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--topology", help="artifact (default: the cached bundled map, without PVS)")
    ap.add_argument("--entities", type=int, default=2000)
    ap.add_argument("--viewers", type=int, default=300)
    ap.add_argument("--seconds", type=float, default=11.0)
    ap.add_argument("--sockets", action="store_true", help="flush through the server's flush loop onto loopback TCP")
    ap.add_argument("--hold-below", type=int, default=0,
                    help="with --sockets: hold frames of fewer states for one more flush (serve --flush-min-frame)")
    ns = ap.parse_args()
    if ns.topology:
        from topology.artifact import load

        topo = load(ns.topology)
    else:
        from entitynet.topology_cache import bundled_topology

        topo, _path = bundled_topology(None, with_pvs=False)
    res = replay(topo, entities=ns.entities, viewers=ns.viewers, seconds=ns.seconds, sockets=ns.sockets,
                 hold_below=ns.hold_below)
    print(json.dumps({**asdict(res), "core_us_per_delivery": res.core_us_per_delivery,
                      "flush_us_per_frame": res.flush_us_per_frame,
                      "total_us_per_delivery": res.total_us_per_delivery}, indent=2))
