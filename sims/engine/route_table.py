"""Every live entity's route in flat arrays, so that where each one is along its route is found for all at once.

Why: `Route.edge_offset` (which edge holds route distance s, and the offset along it) is a bisection and a
clamp in Python, three times per entity for a position (its place and 1 m either side for the lane's
heading): most of what remained of `xy()`'s cost once the geometry went to arrays. Here each route is
registered once, at spawn (`add`: its edges' start distances, edge ids, directions and lengths appended to
growing columns; the entity keeps its rows), and `edge_offsets` finds the edge by a binary search over all
queries at once, with the exact comparisons and clamps of `Route.index` / `Route.edge_offset` (so the results
are theirs, bit for bit). A removed entity's rows become garbage, dropped when they outnumber the live ones
(`compact`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from sims.engine.agents import Agent

_COLUMNS = ("cum", "edge", "dirn", "elen", "rlen")


def route_table_of(world: object) -> RouteTable | None:
    """The world's route table where it is our `World` (its `routes`); None for another source's world."""
    table = getattr(world, "routes", None)
    return table if isinstance(table, RouteTable) else None


class RouteTable:
    """Flat columns of routes: per route edge its start distance `cum`, `edge`, `dirn`, length `elen`, and the
    route's length `rlen`; an agent's rows are `agent._rt` = (first row, edge count)."""

    def __init__(self, edge_len: list[float], slack: int = 4096) -> None:
        self.edge_len = edge_len
        self.slack = slack  # garbage rows tolerated beyond the live ones' count before `compact` rewrites
        self.cum = np.zeros(0)
        self.edge = np.zeros(0, dtype=np.int64)
        self.dirn = np.zeros(0, dtype=np.int64)
        self.elen = np.zeros(0)
        self.rlen = np.zeros(0)
        self.size = 0
        self.live = 0

    def add(self, a: Agent) -> None:
        """Register the agent's route (at spawn): its rows go to `a._rt`."""
        r = a.route
        m = len(r.edges)
        n = self.size
        if n + m > len(self.cum):
            grow = max(1024, len(self.cum), m)
            for name in _COLUMNS:
                col = getattr(self, name)
                setattr(self, name, np.concatenate([col, np.zeros(grow, dtype=col.dtype)]))
        self.cum[n:n + m] = r.cum[:m]
        es, ds = zip(*r.edges, strict=True)
        self.edge[n:n + m] = es
        self.dirn[n:n + m] = ds
        self.elen[n:n + m] = [self.edge_len[e] for e in es]
        self.rlen[n:n + m] = r.length
        a._rt = (n, m)
        self.size = n + m
        self.live += m

    def forget(self, a: Agent) -> None:
        """The agent left the world: its rows are garbage from now on."""
        self.live -= a._rt[1]

    def compact(self, agents: Iterable[Agent]) -> None:
        """Drop the removed agents' rows once they outnumber the live ones (re-registers the live routes)."""
        if self.size <= 2 * self.live + self.slack:
            return
        live = list(agents)
        self.size = self.live = 0
        for a in live:
            self.add(a)

    def rows_at(self, first: np.ndarray, count: np.ndarray, s: np.ndarray) -> np.ndarray:
        """The row of the edge holding route distance `s` on the routes at rows `first`..`first + count`:
        `Route.index` for each (bisect_right on the route's start distances, clamped to the route)."""
        lo, hi = first, first + count
        return np.clip(self.first_row(lo, hi, s, strict=False) - 1, lo, hi - 1)

    def first_row(self, lo: np.ndarray, hi: np.ndarray, q: np.ndarray, *, strict: bool) -> np.ndarray:
        """For each query, the first row in [lo, hi) whose start distance is > q (strict=False: bisect_right) or
        >= q (strict=True: bisect_left); hi when there is none. A binary search over all queries at once."""
        left, right = lo.copy(), hi.copy()
        cum = self.cum
        top = max(len(cum) - 1, 0)
        while True:
            active = left < right
            if not active.any():
                return left
            mid = (left + right) // 2
            c = cum[np.minimum(mid, top)]
            go = (c < q) if strict else (c <= q)
            left = np.where(active & go, mid + 1, left)
            right = np.where(active & ~go, mid, right)

    def edge_offsets(self, first: np.ndarray, count: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(edge, offset along the undirected edge) at route distances `s` of the routes at rows
        `first`..`first + count`: `Route.edge_offset` for each."""
        k = self.rows_at(first, count, s)
        along = s - self.cum[k]
        along = np.where(0.0 > along, 0.0, along)  # max(along, 0.0)
        elen = self.elen[k]
        along = np.where(elen < along, elen, along)  # min(along, edge length)
        return self.edge[k], np.where(self.dirn[k] > 0, along, elen - along)
