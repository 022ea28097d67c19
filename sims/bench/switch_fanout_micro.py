"""Micro-benchmark of the switchboard's per-delivery store: by client id, through a targets handle, compiled.

Why: the replay's cost per delivery mixes per-frame and per-store work; this isolates the store, in CPU time
(`time.process_time`, so preemption by other processes on a shared machine is not counted).
`python -m sims.bench.switch_fanout_micro` prints ns per store for 200 viewer sets of 180 over 1,000 outboxes,
and `news_at_flush` compares the per-delivery stores with computing each viewer's news at flush time with set
operations (the alternative issue 15 asked about): ms of CPU per flush for the same news.
"""

from __future__ import annotations

import random
import time

from entitynet.switchboard import outbox


def measure(rounds: int = 3, reps: int = 20, seed: int = 1) -> list[dict[str, float]]:
    """ns per store for each path and round."""
    rng = random.Random(seed)
    states: dict[int, dict[int, bytes]] = {v: {} for v in range(1000)}
    sets = [set(rng.sample(range(1000), 180)) for _ in range(200)]
    handles = [tuple(states[v] for v in s) for s in sets]
    n = reps * sum(map(len, sets))
    paths = {"by_id_pure": (outbox.fan_out_py, True), "handle_pure": (outbox.fan_out_to_py, False)}
    if outbox.COMPILED is not None:
        paths |= {"by_id_compiled": (outbox.COMPILED.fan_out, True),
                  "handle_compiled": (outbox.COMPILED.fan_out_to, False)}
    out = []
    for _ in range(rounds):
        row = {}
        for name, (fn, by_id) in paths.items():
            t = time.process_time()
            for _ in range(reps):
                for i in range(len(sets)):
                    if by_id:
                        fn(states, sets[i], i, b"x")
                    else:
                        fn(handles[i], i, b"x")
            row[name] = (time.process_time() - t) / n * 1e9
        out.append(row)
    return out


def news_at_flush(n_viewers: int = 1000, n_entities: int = 5000, share: float = 0.19, dirty: int = 50,
                  reps: int = 20, seed: int = 1) -> dict[str, float]:
    """ms of CPU per flush to queue the news of `dirty` updated entities, each seen by `share` of the viewers
    (the standard load: 5,000 entities, 1,000 viewers, 19 %, about 50 updates per 37 ms flush cycle):
    `stores` = one dict store per delivery through the viewer sets' handles (what the core does, compiled where
    built); `sets` = per viewer at flush, `updated & known` (one C set intersection per viewer, unordered: the
    first-queued order would cost a sort on top)."""
    rng = random.Random(seed)
    known = [set(rng.sample(range(n_entities), int(n_entities * share))) for _ in range(n_viewers)]
    states: dict[int, dict[int, bytes]] = {v: {} for v in range(n_viewers)}
    updated = rng.sample(range(n_entities), dirty)
    handles = {e: tuple(states[v] for v in range(n_viewers) if e in known[v]) for e in updated}
    fan = (outbox.COMPILED or outbox.PURE).fan_out_to
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
