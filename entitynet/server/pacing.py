"""Wake-up pacing: at light load the server's loop wakes at most once per `pace` seconds, so that one wake-up
reads, routes and flushes everything that arrived meanwhile (interrupt moderation, as network cards do).

Why: at light load nearly every frame a client sends is its own wake-up of the loop (epoll, the reader task,
the core, the flusher, the NATS link), and such a wake-up costs the interpreter about as much whatever it
carries. A shard of a 4-shard cluster, at a quarter of the load, woke about as often as the single server and
so spent about as much CPU; per delivery, four times as much. Pacing bounds the wake-ups per second instead of
letting the arrival rate set them: after the loop has done a wake-up's work (every task blocked), the pacer
holds the thread (a blocking sleep: nothing runs, the kernel queues what arrives) until `pace` has passed
since the previous paced wake-up began; the next poll then returns everything at once. Under load a wake-up's
work takes longer than `pace` and the pacer never sleeps; with nothing arriving it sleeps in `Event.wait`
(an idle server costs no wake-ups).

The cost is latency, bounded: a message that arrives while the thread is held waits at most `pace` (plus the
wake-up's work) before it is read, replies and timers alike. `ServerConfig.pace` / `entitynet serve --pace-ms`;
0 turns pacing off.
"""

from __future__ import annotations

import time

import trio
from trio.testing import wait_all_tasks_blocked


class Pacer:
    """Call `woke()` whenever input arrived (readers, the NATS link); run `run()` as a task of the server."""

    def __init__(self, pace: float, sleep=time.sleep, clock=time.monotonic):
        self.pace = pace
        self._sleep = sleep  # blocking on purpose: the loop must not poll while it holds
        self._clock = clock
        self._woke = trio.Event()
        self.held_s = 0.0  # total time held (for tests and the bench's notes)
        self.holds = 0

    def woke(self) -> None:
        """Input arrived: the pacer will hold the loop after this wake-up's work if the last began < pace ago."""
        if not self._woke.is_set():
            self._woke.set()

    async def run(self) -> None:
        """Pace forever: wait for input, let every task finish this wake-up's work, then hold the thread for
        what is left of `pace` since the previous paced wake-up began."""
        began = -float("inf")
        while True:
            await self._woke.wait()
            self._woke = trio.Event()
            await wait_all_tasks_blocked()
            await wait_all_tasks_blocked()  # again: the flusher, woken beside us by the first, has now flushed
            now = self._clock()
            hold = began + self.pace - now
            if hold > 0.0:
                self.holds += 1
                self.held_s += hold
                self._sleep(hold)
                now += hold
            began = now
