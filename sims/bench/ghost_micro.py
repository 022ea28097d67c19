"""The ghost table's cost per delivery alone: `python -m sims.bench.ghost_micro [VIEWERS] [UPDATES] [FAN]`.

Why: in a real-time run the table's per-message step is one of the viewers' parts per delivery
(docs/simulation.md); this times it without sockets, the server or the world, so that the pure step
(ENTITYNET_PURE_PYTHON=1) and the compiled one, or two trees, can be alternated in one sitting. Each tick, UPDATES
distinct messages (a fresh seq each, of entities out of 6,000) are each delivered to FAN viewers picked at random
out of VIEWERS, in frames of 6 messages per viewer (as the server writes them at 3,000 / 300), then the queue is
applied (`flush`) as the measure's read would. Payloads are not decoded (the decoder returns its bytes: the shared
decode cache does that work once per distinct payload in a run). Prints CPU us per delivery for `receive` (the
per-message step and the new versions) and `flush`, medians over the ticks after two untimed ones. Runs with the
base tree's code too (it uses only the table's public API)."""

from __future__ import annotations

import json
import os
import random
import statistics
import sys
import time

from entitynet.client import ghost_table
from entitynet.client.ghost_table import GhostTable
from entitynet.protocol import Update


def run(viewers: int = 600, updates: int = 2000, fan: int = 50, ticks: int = 10, frame: int = 6,
        entities: int = 6000) -> dict:
    """CPU us per delivery of the table's `receive` and `flush` (medians over ticks; see the docstring)."""
    rng = random.Random(1)
    table = GhostTable(None, decoder=lambda b: b)
    for _ in range(viewers):
        table.add_viewer()
    recv, flush = [], []
    for tick in range(ticks + 2):
        now = 100.0 + tick
        msgs = [Update(e, tick + 1, (e % 500, (e + 1) % 500), 3000, b"p%d" % e)
                for e in rng.sample(range(entities), updates)]
        per: list[list[Update]] = [[] for _ in range(viewers)]
        for m in msgs:
            for v in rng.sample(range(viewers), fan):
                per[v].append(m)
        frames = [(v, p[k:k + frame]) for v, p in enumerate(per) for k in range(0, len(p), frame)]
        t0 = time.process_time()
        for v, f in frames:
            table.receive(v, f, now, True)
        t1 = time.process_time()
        table.flush()
        t2 = time.process_time()
        if tick >= 2:
            recv.append(1e6 * (t1 - t0) / (updates * fan))
            flush.append(1e6 * (t2 - t1) / (updates * fan))
    return {"receive_us_per_delivery": round(statistics.median(recv), 3),
            "flush_us_per_delivery": round(statistics.median(flush), 3),
            "compiled": getattr(ghost_table, "compiled_in_use", lambda: False)(),
            "viewers": viewers, "updates_per_tick": updates, "fan": fan, "load": os.getloadavg()[0]}


if __name__ == "__main__":
    a = [int(x) for x in sys.argv[1:4]]
    print(json.dumps(run(*a)))
