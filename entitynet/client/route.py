"""A-priori route knowledge of one entity (a tram's or bus's line): which directed edges it will take, in
order, and where it stops.

Kept apart from the tracker because both the tracker (which way to follow at a choice) and the publishing
side (how far the published path is certain, where the next stop is) ask it the same questions.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from entitynet.client.network import DirEdge, NetView
from entitynet.client.path import Path


class Route:
    """The route as directed edges with its pair set and first occurrences (fast membership tests), and the
    known stops by edge. An empty route is falsy: the entity may go anywhere."""

    def __init__(self, net: NetView | None, route: Sequence[Sequence[int]] | None,
                 stops: Sequence[tuple[int, float]] = ()) -> None:
        self.net = net
        self.edges: list[DirEdge] = [(int(e), 1 if d > 0 else -1) for e, d in (route or [])]
        self.pairs = set(zip(self.edges, self.edges[1:], strict=False))
        self.edge_ids = frozenset(e for e, _d in self.edges)  # undirected: the ways the entity may be on
        self.first: dict[DirEdge, int] = {}
        for i, de in enumerate(self.edges):
            self.first.setdefault(de, i)
        self.stops: dict[int, list[float]] = {}
        for e, off in stops:
            self.stops.setdefault(int(e), []).append(float(off))
        self._ku_memo: tuple[Path, int, float] | None = None

    def __bool__(self) -> bool:
        return bool(self.edges)

    def index(self, de: DirEdge) -> int | None:
        """Index of the first occurrence of a directed edge on the route (None: not on it)."""
        return self.first.get(de)

    def known_until(self, path: Path, s: float) -> float:
        """Path coordinate up to which the path follows the a-priori route from the edge holding s."""
        if not self.edges:
            return 0.0
        k0 = path.index(s)
        memo = self._ku_memo
        if memo is not None and memo[0] is path and memo[1] == k0:
            return memo[2]
        k = k0
        edges = path.edges
        i = self.first.get(edges[k])
        if i is None:
            out = 0.0
        elif edges[k:] == self.edges[i : i + len(edges) - k]:
            # the rest of the path is a stretch of the route (the usual case): all its pairs are route pairs,
            # so the walk below would reach the path's end
            out = path.cum[len(edges)]
        else:
            pairs = self.pairs
            n = len(edges)
            while k + 1 < n and (edges[k], edges[k + 1]) in pairs:
                k += 1
            out = path.cum[k + 1]
        self._ku_memo = (path, k0, out)
        return out

    def next_stop(self, path: Path, s: float) -> float:
        """Path coordinate of the next known stop on the a-priori route ahead (inf if none known)."""
        if not self.stops:
            return math.inf
        known = self.known_until(path, s)
        k = path.index(s)
        edges, cum, stops = path.edges, path.cum, self.stops
        n = len(edges)
        while k < n and cum[k] <= known:
            e, d = edges[k]
            offs = stops.get(e)
            if offs:  # the same steps as before, on the few edges that have stops
                for off in sorted(offs, reverse=d < 0):
                    sp = cum[k] + self.net.dist_of((e, d), off)
                    if sp > s + 2.0 and sp <= known:
                        return sp
            k += 1
        return math.inf
