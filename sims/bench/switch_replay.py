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

`python -m sims.bench.switch_replay [--topology FILE] [--entities N] [--viewers N] [--seconds S]` prints the
result as JSON.
"""

from __future__ import annotations

import hashlib
import random
import time
from dataclasses import asdict, dataclass, field

import msgpack

from entitynet import protocol as P
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

    @property
    def core_us_per_delivery(self) -> float:
        """Core time per delivered UPDATE in microseconds (reading, forwarding, draining; no sockets)."""
        return self.core_s * 1e6 / max(self.deliveries, 1)


def replay(topo, *, entities: int = 2000, viewers: int = 300, seconds: float = 11.0, seed: int = 7,
           publisher_connections: int = 4, flush_ms: float = 10.0, radius_m: float = 500.0) -> ReplayResult:
    """Run the switch benchmark's workload through a fresh `Switchboard` for `seconds` of simulated time.

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

    def feed(cid: int, data: bytes, now: float) -> None:
        t = clock()
        dec = P.FrameDecoder()
        dec.receive_data(data)
        while (msgs := dec.next_messages()) is not None:
            sb.receive(cid, msgs, now)
        core[0] += clock() - t

    def flush(now: float) -> None:
        t = clock()
        drained = []
        for cid in sorted(sb.take_dirty()):
            ob = sb.outbox(cid)
            if ob is not None:
                drained.append((cid, b"".join(msgs), msgs) if (msgs := ob.drain()) else None)
        core[0] += clock() - t
        for item in drained:
            if item is None:
                continue
            cid, _joined, msgs = item
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

    for cells in view_cells:
        cid = sb.connect(t0, "viewer")
        hello, _ready = driver.viewer_hello(cells)
        feed(cid, hello, t0)
    pubs = [sb.connect(t0, "publisher") for _ in range(publisher_connections)]
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
    return ReplayResult(h_fwd.hexdigest(), h_ctl.hexdigest(), updates_in, counts["deliveries"], counts["leaves"],
                        counts["frames"], counts["control"], expired, core[0])


if __name__ == "__main__":  # pragma: no cover - a small report tool
    import argparse
    import json

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--topology", help="artifact (default: the cached bundled map, without PVS)")
    ap.add_argument("--entities", type=int, default=2000)
    ap.add_argument("--viewers", type=int, default=300)
    ap.add_argument("--seconds", type=float, default=11.0)
    ns = ap.parse_args()
    if ns.topology:
        from topology.artifact import load

        topo = load(ns.topology)
    else:
        from entitynet.topology_cache import bundled_topology

        topo, _path = bundled_topology(None, with_pvs=False)
    res = replay(topo, entities=ns.entities, viewers=ns.viewers, seconds=ns.seconds)
    print(json.dumps({**asdict(res), "core_us_per_delivery": res.core_us_per_delivery}, indent=2))
