"""When the server process runs Python's full (oldest-generation) garbage collection.

Why: a full collection walks every container object the process holds. A loaded switchboard holds millions of
references (each entity's viewer set, each viewer's outbox, each cell's subscribers), so one takes 0.1-0.2 s
(measured at 10,000 entities and 1,000 viewers: 154-197 ms), during which nothing is read or written. Python
starts one whenever the long-lived heap has grown by a quarter, which is exactly while clients arrive and
subscribe: the pause lands in the traffic, and it grows with the references the server holds. With the policy
on, the objects the server holds from start-up (modules, the topology) are frozen out of collection, automatic
full collections are off, and the server runs one itself every `every` seconds, so the pause comes at a known
rate (and is reported) instead of with growth. (On the 2-core development machine the switch bench's p99 did
not move measurably either way, 100.5 against 104 ms over eight runs each: its tail is set by CPU sharing.)
Young collections (where almost all cyclic garbage dies) are untouched; cyclic garbage that outlives them waits
for the next scheduled pass.

The thresholds are the process's, so only the process's owner turns this on: `entitynet serve` does (its
`--gc-full-every`); a `ServerConfig` built in someone else's process leaves the collector alone by default.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable

import trio

NEVER = 1 << 30  # a third-generation threshold that is never reached: no automatic full collection


class FullCollections:
    """Scheduled full collections for the life of one server; `restore` puts the collector back."""

    def __init__(self, every: float, observe: Callable[[float], None] = lambda s: None):
        if not every > 0:
            raise ValueError(f"the full-collection interval must be > 0 s, not {every!r}")
        self.every = every
        self.observe = observe
        self.pauses: list[float] = []  # the last ten, newest last: readable without scraping /metrics
        self._saved = gc.get_threshold()
        self._froze = False

    def start(self) -> None:
        """Collect once, freeze what survives (start-up state is never garbage) and stop automatic full
        collections."""
        gc.collect()
        gc.freeze()
        self._froze = True
        t0, t1, _t2 = self._saved
        gc.set_threshold(t0, t1, NEVER)

    def collect(self) -> float:
        """One full collection now; its pause in seconds (also given to `observe`)."""
        t = time.perf_counter()
        gc.collect()
        pause = time.perf_counter() - t
        self.pauses = [*self.pauses[-9:], pause]
        self.observe(pause)
        return pause

    def restore(self) -> None:
        """Python's own thresholds again, and the frozen objects back in collection."""
        gc.set_threshold(*self._saved)
        if self._froze:
            gc.unfreeze()
            self._froze = False

    async def run(self) -> None:
        """After `start`: a full collection every `every` seconds until cancelled, then `restore`."""
        try:
            while True:
                await trio.sleep(self.every)
                self.collect()
        finally:
            self.restore()
