"""Rate limits: token buckets for per-client request rates (queries, subscription churn), and a back-off for failed
logins per peer."""

from __future__ import annotations


class TokenBucket:
    """A classic token bucket fed an explicit `now`: bounds a client's query rate and subscription churn with a
    burst allowance, so that one client cannot make the switch do unbounded work."""

    __slots__ = ("rate", "burst", "tokens", "last")

    def __init__(self, rate: float, burst: float, now: float):
        self.rate = rate
        self.burst = burst
        self.tokens = burst
        self.last = now

    def take(self, now: float, n: float = 1.0) -> bool:
        """Spend `n` tokens if there are that many (all or nothing). Time going backwards refills nothing."""
        if now > self.last:
            self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
            self.last = now
        if self.tokens >= n:
            self.tokens -= n
            return True
        return False


class FailureThrottle:
    """Exponential back-off of failed logins per peer address (sans-IO: every call takes `now`).

    The first `free` failures of a peer cost nothing (typos); each further one blocks that peer for
    `base * 2**k` seconds (k = 0, 1, 2, ...), at most `cap`. While blocked, a login from the peer is refused
    without looking at its token, so guessing learns nothing and costs the server one dict lookup; refused
    attempts do not lengthen the block (an honest client retrying with back-off gets in when it ends).
    A success does not reset the count (else one valid token would launder any number of guesses); a peer
    is forgotten after `10 * cap` seconds without failures once its block has ended (long enough that
    waiting for the reset is slower than guessing at the capped rate). At most `max_peers` are
    remembered: beyond that the expired ones, then the oldest, are forgotten.

    With the defaults (3 free, 1 s, cap 60 s) 300 wrong tokens from one address take about 4.8 hours
    instead of a fraction of a second.
    """

    __slots__ = ("free", "base", "cap", "max_peers", "_peers")

    def __init__(self, free: int = 3, base: float = 1.0, cap: float = 60.0, max_peers: int = 65_536):
        if free < 0 or base <= 0 or cap < base or max_peers < 1:
            raise ValueError("need free >= 0, 0 < base <= cap and max_peers >= 1")
        self.free = free
        self.base = base
        self.cap = cap
        self.max_peers = max_peers
        self._peers: dict[str, list[float]] = {}  # key -> [failures, blocked until]; oldest first

    def retry_after(self, key: str, now: float) -> float:
        """Seconds until `key` may try again (0.0: now)."""
        st = self._peers.get(key)
        if st is None:
            return 0.0
        return max(0.0, st[1] - now)

    def failed(self, key: str, now: float) -> float:
        """Count a failed login of `key`; returns how long it is now blocked (0.0 within the free ones)."""
        st = self._peers.pop(key, None)
        if st is None or now > st[1] + 10 * self.cap:
            st = [0.0, now]
        st[0] += 1
        over = int(st[0]) - self.free
        block = 0.0 if over <= 0 else min(self.cap, self.base * 2.0 ** min(over - 1, 62))
        st[1] = max(st[1], now + block)
        self._peers[key] = st  # re-inserted: the dict stays ordered by last failure
        if len(self._peers) > self.max_peers:
            self._forget(now)
        return block

    def _forget(self, now: float) -> None:
        quiet = 10 * self.cap
        for k in [k for k, st in self._peers.items() if now > st[1] + quiet]:
            del self._peers[k]
        while len(self._peers) > self.max_peers:
            del self._peers[next(iter(self._peers))]

    def __len__(self) -> int:
        return len(self._peers)
