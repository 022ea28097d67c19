"""Viewer subscriptions (reference section 4.4): camera -> view cell -> PVS -> one SUBSCRIBE difference.

`cells_at(x, y, z)` is any callable giving the visibility cells potentially visible from that camera position
(the PVS lookup of `topology/pvs.py`, or a stub in tests): this core does not care how it is computed.
Direct subscriptions (FOLLOW) are bounded by the server's limit, entity queries by a minimum interval; both
limits come from WELCOME and are enforced here so a well-behaved client never trips the server's.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable

from entitynet.protocol import QUERY_CELLS, QUERY_IDENTITY, Follow, Query, Subscribe, Unfollow


class LimitExceeded(ValueError):
    """A direct subscription or query beyond the server's limits."""


class Subscriptions:
    """A viewer's subscription state (PVS cells, follows, query pacing) that turns camera moves into
    SUBSCRIBE differences and keeps within the server's limits before the server has to refuse."""

    def __init__(self, cells_at: Callable[[float, float, float], Iterable[int]], *, max_follows: int = 16,
                 query_interval: float = 1.0, max_subscriptions: int | None = None) -> None:
        self.cells_at = cells_at
        self.max_follows = max_follows
        self.query_interval = query_interval
        self.max_subscriptions = max_subscriptions  # None: no cap until a WELCOME announces one
        self.cells: frozenset[int] = frozenset()
        self.follows: set[int] = set()
        self._last_query = -math.inf
        self._query_id = 0

    def apply_limits(self, limits: dict[str, int]) -> None:
        """Adopt the limits a WELCOME announced (unknown keys are ignored), so that this client never sends
        what the server would refuse: a SUBSCRIBE over `max_subscriptions` is refused whole."""
        if "max_subscriptions" in limits:
            self.max_subscriptions = max(0, int(limits["max_subscriptions"]))
        if "max_follows" in limits:
            self.max_follows = int(limits["max_follows"])
        if "query_rate_mhz" in limits:  # the server's token bucket refills at this rate (milli-queries/s)
            rate = int(limits["query_rate_mhz"]) / 1000.0
            self.query_interval = 1.0 / rate if rate > 0 else math.inf

    def move_camera(self, x: float, y: float, z: float) -> list[Subscribe]:
        """The SUBSCRIBE difference for a camera at (x, y, z); empty when the PVS did not change."""
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise ValueError(f"camera position must be finite, got ({x!r}, {y!r}, {z!r})")
        return self.set_cells([int(c) for c in self.cells_at(x, y, z)])

    def set_cells(self, new: Iterable[int]) -> list[Subscribe]:
        """The SUBSCRIBE difference to the cells `new`, of which only the first `max_subscriptions` (in the
        order given: list the most wanted first) are kept when there are more."""
        new = list(new)
        cap = self.max_subscriptions
        if cap is not None and len(new) > cap:
            new = list(dict.fromkeys(new))[:cap]  # duplicates dropped first, so they do not use up the cap
        new = frozenset(new)
        added = tuple(sorted(new - self.cells))
        removed = tuple(sorted(self.cells - new))
        self.cells = new
        if not added and not removed:
            return []
        return [Subscribe(added, removed)]

    def follow(self, entity: int) -> list[Follow]:
        """FOLLOW an entity wherever it goes (nothing if already followed); raises `LimitExceeded` past
        `max_follows` so the server's limit is never tripped."""
        if entity in self.follows:
            return []
        if len(self.follows) >= self.max_follows:
            raise LimitExceeded(f"at most {self.max_follows} direct subscriptions")
        self.follows.add(entity)
        return [Follow(entity)]

    def unfollow(self, entity: int) -> list[Unfollow]:
        """Stop following an entity (nothing to send if it was not followed)."""
        if entity not in self.follows:
            return []
        self.follows.discard(entity)
        return [Unfollow(entity)]

    def query(self, now: float, *, identity: str | None = None, cells: Iterable[int] | None = None) -> list[Query]:
        """An entity query by published identity or by cells, at most one per `query_interval`."""
        if (identity is None) == (cells is None):
            raise ValueError("query by exactly one of identity or cells")
        if now - self._last_query < self.query_interval:
            raise LimitExceeded(f"at most one query per {self.query_interval:g} s")
        self._last_query = now
        self._query_id += 1
        if identity is not None:
            return [Query(self._query_id, QUERY_IDENTITY, identity)]
        return [Query(self._query_id, QUERY_CELLS, tuple(sorted({int(c) for c in cells})))]
