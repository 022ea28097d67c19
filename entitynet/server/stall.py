"""Stall accounting for blocked writes, sans-IO: time only what the client fails to read.

A write that the kernel does not take is blocked because the client does not read, or because the server's
own loop was busy (one huge frame, a long flush) and could not move bytes. Only the first is the client's fault.
So the stall of a connection is not `now - write started`: it is accumulated tick by tick by the housekeeping
loop, each tick crediting at most `max_credit` seconds (a tick that comes late means the loop was frozen, and a
frozen loop could not have observed progress), and it is reset whenever the writer observes progress (the
kernel took bytes).
"""

from __future__ import annotations


class StallClock:
    """Turns the housekeeping loop's ticks into stall credit: the time since the previous tick, capped."""

    __slots__ = ("max_credit", "last")

    def __init__(self, max_credit: float):
        self.max_credit = max_credit
        self.last: float | None = None

    def tick(self, now: float) -> float:
        """Seconds to add to every blocked write's stall now (0 on the first tick or if time went back)."""
        last, self.last = self.last, now
        if last is None or now <= last:
            return 0.0
        return min(now - last, self.max_credit)
