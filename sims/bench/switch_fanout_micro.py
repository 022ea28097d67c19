"""Micro-benchmark of the switchboard's per-delivery store: by client id or through a targets handle, into the dict
outboxes (the reference) or the compiled ones (`_outbox.pyx`).

Why: the replay's cost per delivery mixes per-frame and per-store work; this isolates the store, in CPU time
(`time.process_time`, so preemption by other processes on a shared machine is not counted).
`python -m sims.bench.switch_fanout_micro` prints ns per store for 200 viewer sets of 180 over 1,000 outboxes,
and `news_at_flush` compares the per-delivery stores with computing each viewer's news at flush time with set
operations (the alternative issue 15 asked about): ms of CPU per flush for the same news.
"""

from __future__ import annotations

import random
import time
from typing import Any

from entitynet.switchboard import outbox


def _tables(n_viewers: int) -> dict[str, tuple[Any, list]]:
    """The dict outboxes (the reference) and, where built, the compiled table, each with `n_viewers` open:
    (table, the outboxes)."""
    kinds = {"pure": outbox.Outboxes} | ({"compiled": outbox.TABLE} if outbox.TABLE is not None else {})
    out = {}
    for name, kind in kinds.items():
        table = kind(10**6, 10)
        out[name] = (table, [table.open(v) for v in range(n_viewers)])
    return out


def measure(rounds: int = 3, reps: int = 20, seed: int = 1) -> list[dict[str, float]]:
    """ns per store for each path and round (the outboxes are drained after each rep: every store a new one)."""
    rng = random.Random(seed)
    sets = [set(rng.sample(range(1000), 180)) for _ in range(200)]
    n = reps * sum(map(len, sets))
    tables = _tables(1000)
    handles = {name: [t.targets(s) for s in sets] for name, (t, _) in tables.items()}
    out = []
    for _ in range(rounds):
        row = {}
        for name, (table, boxes) in tables.items():
            for by_id in (True, False):
                spent = 0.0
                for _ in range(reps):
                    t = time.process_time()
                    for i in range(len(sets)):
                        if by_id:
                            table.fan_out(sets[i], i, b"x")
                        else:
                            table.fan_out_to(handles[name][i], i, b"x")
                    spent += time.process_time() - t
                    for ob in boxes:
                        ob.discard_states()
                row[("by_id_" if by_id else "handle_") + name] = spent / n * 1e9
        out.append(row)
    return out


def news_at_flush(n_viewers: int = 1000, n_entities: int = 5000, share: float = 0.19, dirty: int = 50,
                  reps: int = 20, seed: int = 1) -> dict[str, float]:
    """ms of CPU per flush to queue the news of `dirty` updated entities, each seen by `share` of the viewers
    (the standard load: 5,000 entities, 1,000 viewers, 19 %, about 50 updates per 37 ms flush cycle):
    `stores` = one store per delivery through the viewer sets' handles (what the core does: the compiled
    outboxes where built); `sets` = per viewer at flush, `updated & known` (one C set intersection per viewer,
    unordered: the first-queued order would cost a sort on top)."""
    rng = random.Random(seed)
    known = [set(rng.sample(range(n_entities), int(n_entities * share))) for _ in range(n_viewers)]
    updated = rng.sample(range(n_entities), dirty)
    table, _boxes = _tables(n_viewers).popitem()[1]  # the compiled one where built
    handles = {e: table.targets(v for v in range(n_viewers) if e in known[v]) for e in updated}
    fan = table.fan_out_to
    t = time.process_time()
    for _ in range(reps):
        for e in updated:
            fan(handles[e], e, b"x")
    stores = (time.process_time() - t) / reps
    upd = set(updated)
    t = time.process_time()
    for _ in range(reps):
        for v in range(n_viewers):
            upd & known[v]  # noqa: B018 - the set operation is what is timed
    sets = (time.process_time() - t) / reps
    return {"deliveries": float(sum(map(len, handles.values()))), "stores_ms": stores * 1e3, "sets_ms": sets * 1e3}


if __name__ == "__main__":  # pragma: no cover - a small report tool
    for row in measure():
        print("  ".join(f"{k} {v:.0f} ns" for k, v in row.items()))
    for d in (50, 200):
        r = news_at_flush(dirty=d)
        print(f"{d} updated entities, {r['deliveries']:.0f} deliveries per flush: per-delivery stores "
              f"{r['stores_ms']:.2f} ms, set intersections at flush {r['sets_ms']:.2f} ms")
