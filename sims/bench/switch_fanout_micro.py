"""Micro-benchmark of the switchboard's per-delivery store: by client id, through a targets handle, compiled.

Why: the replay's cost per delivery mixes per-frame and per-store work; this isolates the store, in CPU time
(`time.process_time`, so preemption by other processes on a shared machine is not counted).
`python -m sims.bench.switch_fanout_micro` prints ns per store for 200 viewer sets of 180 over 1,000 outboxes.
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


if __name__ == "__main__":  # pragma: no cover - a small report tool
    for row in measure():
        print("  ".join(f"{k} {v:.0f} ns" for k, v in row.items()))
