"""Micro-benchmark of the switchboard's per-PUBLISH path: `Switchboard.receive` of frames of PUBLISHes when
each PUBLISH reaches few viewers, on three paths in one process, alternated.

Why: at the standard load a PUBLISH reaches about 160 viewers, so the per-delivery work (the route, the flush)
hides the per-PUBLISH bookkeeping in the replay's and the live bench's noise; at light load and on shards a
PUBLISH reaches a few, and the bookkeeping is the cost. This isolates it, in CPU time (`time.process_time`, so
preemption by other processes on a shared machine is not counted). The paths:
`pure` (ENTITYNET_PURE_PYTHON's: everything in Python), `route` (the compiled route and fan-out, `_publish` and
`_apply_state` in Python: the code before `_fanout.publish_run`), `run` (`_fanout.publish_run`: the common
PUBLISH in one C loop). Every path must leave the same bytes in the outboxes (`digest`), or the result says so.

`python -m sims.bench.switch_publish_micro [--rounds 5]` prints µs of CPU per PUBLISH per path and round.
"""

from __future__ import annotations

import hashlib
import random
import statistics
import time

from entitynet import protocol as P
from entitynet.switchboard import Switchboard, SwitchConfig, outbox


def _workload(n_entities: int, n_frames: int, per_frame: int, n_cells: int, seed: int) -> list[list[P.Publish]]:
    """Frames of PUBLISHes: every entity once first, then random entities, 30 % of them moving to 1-2 new cells
    (the rest updating in place), with 40-byte payloads."""
    rng = random.Random(seed)
    cells = [tuple(rng.sample(range(n_cells), rng.choice((1, 2)))) for _ in range(n_entities)]
    seq = [0] * n_entities
    order = list(range(n_entities)) + [rng.randrange(n_entities) for _ in range(n_frames * per_frame)]
    msgs = []
    for i in order:
        seq[i] += 1
        if seq[i] > 1 and rng.random() < 0.3:
            cells[i] = tuple(rng.sample(range(n_cells), rng.choice((1, 2))))
        msgs.append(P.Publish(i, seq[i], cells[i], 5000 + rng.randrange(10_000), bytes(40)))
    return [msgs[k:k + per_frame] for k in range(0, len(msgs), per_frame)]


def _one(path: str, frames: list[list[P.Publish]], n_cells: int, n_viewers: int, cells_per_viewer: int,
         seed: int, warm: int) -> tuple[float, int, str]:
    """Play the frames on `path`: CPU seconds inside `receive` for the frames after `warm` (the first publish of
    every entity is set-up), PUBLISHes timed, and a digest of every outbox's bytes after every frame."""
    outbox.use_compiled(path != "pure")
    if path == "route":
        outbox._publish_run = None
    rng = random.Random(seed)
    sb = Switchboard(SwitchConfig(n_cells=n_cells, digest="d", open_mode=True, seed=seed))
    hello = P.Hello(P.PROTOCOL_VERSION, "", "d")
    viewers = [sb.connect(0.0) for _ in range(n_viewers)]
    for v in viewers:
        sb.receive(v, [hello, P.Subscribe(tuple(rng.sample(range(n_cells), cells_per_viewer)), ())], 0.0)
    pub = sb.connect(0.0)
    sb.receive(pub, [hello], 0.0)
    h = hashlib.sha256()
    cpu, timed = 0.0, 0
    for k, frame in enumerate(frames):
        now = 1.0 + k * 0.005
        t = time.process_time()
        sb.receive(pub, frame, now)
        if k >= warm:
            cpu += time.process_time() - t
            timed += len(frame)
        for cid in sorted(sb.take_dirty()):
            ob = sb.outbox(cid)
            if ob is not None:
                h.update(b"%d:" % cid + b"".join(ob.drain()))
    return cpu, timed, h.hexdigest()[:16]


def measure(rounds: int = 5, n_entities: int = 5000, n_frames: int = 300, per_frame: int = 200,
            n_cells: int = 1721, n_viewers: int = 20, cells_per_viewer: int = 100, seed: int = 1) -> dict:
    """µs of CPU per PUBLISH on each path, per round (alternated) and the medians; `same_bytes` says whether
    every path queued exactly the same bytes."""
    paths = ["pure"] + (["route", "run"] if outbox.COMPILED is not None else [])
    frames = _workload(n_entities, n_frames, per_frame, n_cells, seed)
    warm = -(-n_entities // per_frame)
    was = outbox.compiled_in_use()
    rows, digests = [], set()
    try:
        for _ in range(rounds):
            row = {}
            for path in paths:
                cpu, timed, digest = _one(path, frames, n_cells, n_viewers, cells_per_viewer, seed, warm)
                row[path] = cpu * 1e6 / max(timed, 1)
                digests.add(digest)
            rows.append(row)
    finally:
        outbox.use_compiled(was)
    return {"us_per_publish": rows, "medians": {p: statistics.median(r[p] for r in rows) for p in paths},
            "same_bytes": len(digests) == 1, "publishes_timed": n_frames * per_frame}


if __name__ == "__main__":  # pragma: no cover - a small report tool
    import argparse
    import json

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--viewers", type=int, default=20)
    ap.add_argument("--cells-per-viewer", type=int, default=100)
    ns = ap.parse_args()
    print(json.dumps(measure(ns.rounds, n_viewers=ns.viewers, cells_per_viewer=ns.cells_per_viewer), indent=2))
