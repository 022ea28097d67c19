"""Trajectories on the street network: where an entity can start, and the edges it goes along.

Two shapes of path, for two kinds of run: `Trajectory` grows edge by edge as the mover advances (open-ended
runs such as the demo: a random turn at every junction, turning back at dead ends and areas), and
`random_walk` draws a whole path of about a given length up front (benchmarks that sample a finite truth).
Both draw from the caller's `random.Random`, so a seed reproduces a run exactly.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from entitynet.client.network import DirEdge, NetView


def random_start(net: NetView, networks: int, rng: random.Random) -> DirEdge:
    """A random directed edge of the given networks, longer than 5 m (shorter ones are mostly junction
    stubs, where a start would be ambiguous)."""
    candidates = [e for e in range(net.n_edges) if net.edge_net[e] & networks and net.edge_len[e] > 5.0]
    if not candidates:
        raise ValueError("the map has no edge of this entity type's network")
    return candidates[rng.randrange(len(candidates))], rng.choice((1, -1))


@dataclass
class Trajectory:
    """A mover's true position: distance `s` along a list of directed edges that grows ahead of it and is
    trimmed behind it, so an open-ended run keeps a bounded path."""

    net: NetView
    networks: int
    rng: random.Random
    path: list[DirEdge] = field(default_factory=list)
    lengths: list[float] = field(default_factory=list)
    s: float = 0.0  # distance travelled along path[0] onwards
    base: float = 0.0  # distance of path[0]'s start (the path is trimmed behind the mover)

    @classmethod
    def starting_at(cls, net: NetView, networks: int, rng: random.Random, start: DirEdge) -> Trajectory:
        """A trajectory at the start of `start` (the caller may then place it along the edge with `s`)."""
        return cls(net, networks, rng, [start], [net.edge_len[start[0]]])

    def extend(self) -> None:
        """Append the next edge: a random choice at the end node, or back along the last edge at a dead end
        or an area node (areas are walked by `area_walk`, not crossed along edges)."""
        last = self.path[-1]
        choices = self.net.choices(last, self.networks)
        if self.net.node_area[self.net.end_node(last)] >= 0 or not choices:
            nxt = (last[0], -last[1])  # dead end or area: turn back
        else:
            nxt = choices[self.rng.randrange(len(choices))]
        self.path.append(nxt)
        self.lengths.append(self.net.edge_len[nxt[0]])

    def advance(self, ds: float) -> None:
        """Move `ds` metres ahead (negative counts as 0), growing the path ahead and trimming it behind."""
        self.s += max(ds, 0.0)
        while self.s - self.base > sum(self.lengths) - 1e-9:
            self.extend()
        while len(self.path) > 1 and self.s - self.base > self.lengths[0]:
            self.base += self.lengths.pop(0)
            self.path.pop(0)

    def position(self) -> tuple[float, float]:
        """The true local (x, y) of the mover."""
        edge, d = self.path[0]
        local = min(self.s - self.base, self.lengths[0])
        return self.net.point(edge, local if d > 0 else self.lengths[0] - local)


def random_walk(net: NetView, start: DirEdge, networks: int, length: float, rng: random.Random) -> list[DirEdge]:
    """A random path of about `length` metres (at most 500 edges); stops early at dead ends and area nodes,
    and never turns back, so the path is a plausible route rather than a dither."""
    edges = [start]
    total = net.edge_len[start[0]]
    while total < length and len(edges) < 500:
        ch = [c for c in net.choices(edges[-1], networks) if net.node_area[net.end_node(edges[-1])] < 0]
        if not ch:
            break
        nxt = ch[rng.randrange(len(ch))]
        edges.append(nxt)
        total += net.edge_len[nxt[0]]
    return edges
