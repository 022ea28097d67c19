"""The server-minus-local clock offset, estimated from PING/PONG round trips (sans-IO, no clock of its own)."""

from __future__ import annotations

import math
from collections import deque


class ClockEstimate:
    """Server-minus-local clock offset from PING/PONG, best (smallest round trip) of the last samples.

    Why the smallest round trip: a sample's error is at most half its round trip, so the fastest recent exchange
    bounds the error best; keeping only the last few lets the estimate follow a drifting clock.
    """

    def __init__(self, keep: int = 8):
        self.samples: deque[tuple[float, float]] = deque(maxlen=keep)  # (rtt_s, offset_s)

    def add(self, sent_s: float, received_s: float, server_s: float) -> bool:
        """Record one exchange; False (and nothing kept) when the times are not finite or the local clock went
        backwards between sending and receiving, since such a sample would only mislead."""
        if not (math.isfinite(sent_s) and math.isfinite(received_s) and math.isfinite(server_s)):
            return False
        rtt = received_s - sent_s
        if rtt < 0:
            return False
        self.samples.append((rtt, server_s - (sent_s + received_s) / 2.0))
        return True

    def clear(self) -> None:
        """Forget every sample: another server's clock (after a REDIRECT) says nothing about this one's."""
        self.samples.clear()

    @property
    def offset(self) -> float | None:
        """Server clock minus local clock in seconds, or None before the first PONG."""
        return min(self.samples)[1] if self.samples else None

    @property
    def rtt(self) -> float | None:
        """The round trip of the sample the offset comes from (twice its worst-case error)."""
        return min(self.samples)[0] if self.samples else None
