"""Load walkers: many cheap entities at constant speed on the raw street graph, for switchboard load.

Why not the simulation's honest clients: a switchboard benchmark needs thousands of publishers at a few
hundred updates per second from one Python process, and measures the server, not dead reckoning. So these
walkers skip the client core: each one sends an update when its cell-occupation validity runs out (the front
reaches the next cell breakpoint) and otherwise every 5-15 s, the cadence an honest client produces; cars,
longer than a breakpoint gap now and then, occupy two cells. Updates are due from a heap, so a tick costs only
what is due.
"""

from __future__ import annotations

import heapq
import random

import numpy as np

from sims.mobility.kinds import KINDS

#: constant speeds (m/s) of the load walkers: the switch benchmark's figures were measured with these
LOAD_SPEEDS = {"pedestrian": 1.4, "car": 8.0}
#: share of cars among the load walkers
LOAD_CAR_SHARE = 0.3


class Walkers:
    """Entities moving on the street graph; `start(now)` and `due(now)` give (entity, cells, validity_ms) of
    their updates, and `seq[i]` is entity i's sequence number of the latest one."""

    def __init__(self, topo, n: int, rng: random.Random):
        self.topo = topo
        self.rng = rng
        self.length = topo.edge_length.astype(float)
        self.edge_nodes = topo.edge_nodes
        self.n = n
        self.car_length = KINDS["car"].length
        usable = np.flatnonzero(self.length > 1.0)
        self.edge = [int(rng.choice(usable)) for _ in range(n)]
        self.off = [rng.uniform(0, self.length[e]) for e in self.edge]
        self.dir = [rng.choice((1, -1)) for _ in range(n)]
        self.car = [rng.random() < LOAD_CAR_SHARE for _ in range(n)]
        self.speed = [LOAD_SPEEDS["car"] if c else LOAD_SPEEDS["pedestrian"] for c in self.car]
        self.seq = [0] * n
        self.t = [0.0] * n
        self.heap: list[tuple[float, int]] = []

    def start(self, now: float) -> list[tuple[int, tuple[int, ...], int]]:
        """Every walker's first update at `now`."""
        out = []
        for i in range(self.n):
            self.t[i] = now
            out.append(self._update(i, now))
        return out

    def due(self, now: float) -> list[tuple[int, tuple[int, ...], int]]:
        """The updates due by `now` (each walker moved to `now` first)."""
        out = []
        heap = self.heap
        while heap and heap[0][0] <= now:
            _, i = heapq.heappop(heap)
            self._advance(i, now)
            out.append(self._update(i, now))
        return out

    def _advance(self, i: int, now: float) -> None:
        dist = self.speed[i] * max(0.0, now - self.t[i])
        self.t[i] = now
        e, s, d = self.edge[i], self.off[i] + self.dir[i] * dist, self.dir[i]
        for _ in range(100):
            L = self.length[e]
            if 0.0 <= s <= L:
                break
            over = s - L if s > L else -s
            node = int(self.edge_nodes[e][1] if s > L else self.edge_nodes[e][0])
            cand = [int(x) for x in self.topo.edges_of_node(node) if int(x) != e] or [e]
            e = self.rng.choice(cand)
            if int(self.edge_nodes[e][0]) == node:
                d, s = 1, min(over, self.length[e])
            else:
                d, s = -1, max(self.length[e] - over, 0.0)
        self.edge[i], self.off[i], self.dir[i] = e, min(max(s, 0.0), self.length[e]), d

    def _update(self, i: int, now: float) -> tuple[int, tuple[int, ...], int]:
        e, s, d = self.edge[i], self.off[i], self.dir[i]
        starts, cells = self.topo.cell_pieces(e)
        k = max(int(np.searchsorted(starts, s, side="right")) - 1, 0)
        occ = [int(cells[k])]
        if self.car[i]:
            aft = min(max(s - d * self.car_length, 0.0), self.length[e])
            ka = max(int(np.searchsorted(starts, aft, side="right")) - 1, 0)
            if ka != k:
                occ.append(int(cells[ka]))
        # validity: until the front reaches the next breakpoint (or the edge end) in its direction
        if d > 0:
            nxt = float(starts[k + 1]) if k + 1 < len(starts) else self.length[e]
            gap = nxt - s
        else:
            gap = s - float(starts[k])
        validity = min(60.0, max(0.5, gap / self.speed[i]))
        refresh = self.rng.uniform(5.0, 15.0)
        heapq.heappush(self.heap, (now + min(validity, refresh), i))
        self.seq[i] += 1
        return i, tuple(dict.fromkeys(occ)), int(validity * 1000)
