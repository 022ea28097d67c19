"""Routes: a connected list of directed edges with distances along it, and origin-destination trips.

Why a route object rather than the mobility model's growing `Trajectory`: the engine's vehicles must look
ahead along the way they will really take (to follow a leader, stop at a bus stop, reserve a crossing), so the
whole path is known when the entity spawns: an OD trip's shortest path, or a transit line's a-priori route.

Trips never pass *through* an area node: an edge that serves an area is clipped at the area's boundary while
the node sits at its centre, so a path through it would jump across the area (areas are walked, not crossed
along edges). An area node may be a trip's destination (the walk inside it follows).

Shortest paths: no scipy, so Dijkstra in pure Python from a bounded pool of destination nodes (one tree each,
built lazily and cached); a trip goes from a random origin edge to one of the pool's destinations along that
tree. This keeps the start-up cost bounded (pool size x one Dijkstra) whatever the number of entities.
"""

from __future__ import annotations

import heapq
import math
import random
from bisect import bisect_right

from entitynet.client.network import DirEdge, NetView


class Route:
    """Directed edges `edges`, each starting where the previous one ends; `cum[k]` is the distance from the
    route's start to the start of edge k, `length` the total."""

    __slots__ = ("net", "edges", "cum", "length")

    def __init__(self, net: NetView, edges: list[DirEdge]):
        if not edges:
            raise ValueError("a route needs at least one edge")
        for a, b in zip(edges, edges[1:], strict=False):
            if net.end_node(a) != net.start_node(b):
                raise ValueError(f"route is not connected between {a} and {b}")
        self.net = net
        self.edges = list(edges)
        cum = [0.0]
        for e, _d in self.edges:
            cum.append(cum[-1] + net.edge_len[e])
        self.cum = cum
        self.length = cum[-1]

    def index(self, s: float) -> int:
        """The index of the edge holding route distance `s` (clamped to the route)."""
        k = bisect_right(self.cum, s) - 1
        return min(max(k, 0), len(self.edges) - 1)

    def edge_offset(self, s: float) -> tuple[int, float]:
        """(edge, offset along the edge) at route distance `s`."""
        k = self.index(s)
        e, d = self.edges[k]
        along = min(max(s - self.cum[k], 0.0), self.net.edge_len[e])
        return e, (along if d > 0 else self.net.edge_len[e] - along)

    def xy(self, s: float, lateral: float = 0.0) -> tuple[float, float]:
        """Local (x, y) at route distance `s`, shifted `lateral` metres to the right of the direction of travel."""
        e, off = self.edge_offset(s)
        x, y = self.net.point(e, off)
        if lateral == 0.0:
            return x, y
        hx, hy = self.heading(s)
        return x + lateral * hy, y - lateral * hx

    def heading(self, s: float) -> tuple[float, float]:
        """Unit direction of travel at `s` (from points 1 m either side; (1, 0) on a degenerate route)."""
        a = self.xy(max(s - 1.0, 0.0))
        b = self.xy(min(s + 1.0, self.length))
        dx, dy = b[0] - a[0], b[1] - a[1]
        n = math.hypot(dx, dy)
        return (dx / n, dy / n) if n > 1e-9 else (1.0, 0.0)

    def cell(self, s: float) -> int:
        """The visibility cell at route distance `s`."""
        e, off = self.edge_offset(s)
        return self.net.cell_at(e, off)

    def nodes(self) -> list[tuple[float, int, int]]:
        """(route distance, node, index of the edge leaving it) of every node between two edges of the route."""
        return [(self.cum[k], self.net.start_node(self.edges[k]), k) for k in range(1, len(self.edges))]


class Router:
    """Shortest paths on one network (bit mask) to a pool of destination nodes, for OD trips."""

    def __init__(self, net: NetView, networks: int, rng: random.Random, pool: int = 48):
        self.net = net
        self.networks = networks
        self.edges = [e for e in range(net.n_edges) if net.edge_net[e] & networks and net.edge_len[e] > 1.0]
        if not self.edges:
            raise ValueError("the map has no edge of this network")
        nodes = sorted({net.edge_from[e] for e in self.edges} | {net.edge_to[e] for e in self.edges})
        # destinations: ordinary nodes (not areas) so a trip ends on a street
        plain = [n for n in nodes if net.node_area[n] < 0] or nodes
        self.pool = rng.sample(plain, min(pool, len(plain)))
        self._trees: dict[int, dict[int, tuple[float, DirEdge | None]]] = {}

    def tree(self, dest: int) -> dict[int, tuple[float, DirEdge | None]]:
        """node -> (distance to `dest`, first directed edge of the shortest path from that node to `dest`)."""
        hit = self._trees.get(dest)
        if hit is not None:
            return hit
        net = self.net
        best: dict[int, tuple[float, DirEdge | None]] = {dest: (0.0, None)}
        heap = [(0.0, dest)]
        done: set[int] = set()
        while heap:
            dist, n = heapq.heappop(heap)
            if n in done:
                continue
            done.add(n)
            if n != dest and net.node_area[n] >= 0:
                continue  # no way *through* an area: its edges stop at its boundary, the node is its centre
            for e in net.node_edges[n]:
                if not net.edge_net[e] & self.networks:
                    continue
                other = net.edge_to[e] if net.edge_from[e] == n else net.edge_from[e]
                nd = dist + net.edge_len[e]
                if nd < best.get(other, (math.inf, None))[0]:
                    # from `other` the path goes along e towards n
                    best[other] = (nd, (e, 1 if net.edge_from[e] == other else -1))
                    heapq.heappush(heap, (nd, other))
        self._trees[dest] = best
        return best

    def path(self, start: DirEdge, dest: int) -> list[DirEdge] | None:
        """`start` then the shortest path from its end node to `dest` (None if unreachable); when that path
        begins by going straight back along `start`, the trip starts on the reversed edge instead."""
        tree = self.tree(dest)
        n = self.net.end_node(start)
        if n not in tree or (n != dest and self.net.node_area[n] >= 0):
            return None
        rest: list[DirEdge] = []
        for _ in range(self.net.n_edges + 1):
            nxt = tree[n][1]
            if nxt is None:
                break
            rest.append(nxt)
            n = self.net.end_node(nxt)
        if rest and rest[0] == (start[0], -start[1]):
            return rest
        return [start, *rest]

    def trip(self, rng: random.Random, min_length: float = 200.0, tries: int = 20) -> list[DirEdge]:
        """A random OD trip: a random origin edge and direction, a random pool destination, at least
        `min_length` metres when one can be found in `tries` draws (else the longest found)."""
        best: list[DirEdge] = []
        best_len = -1.0
        for _ in range(tries):
            start = (self.edges[rng.randrange(len(self.edges))], rng.choice((1, -1)))
            path = self.path(start, self.pool[rng.randrange(len(self.pool))])
            if path is None:
                continue
            length = sum(self.net.edge_len[e] for e, _ in path)
            if length >= min_length:
                return path
            if length > best_len:
                best, best_len = path, length
        if not best:
            raise ValueError("no trip found on this network (disconnected map?)")
        return best
