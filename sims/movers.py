"""Simulated movers for the demo and load runs: a true trajectory on the network, GPS fixes, a client core.

A mover walks (or drives) a random path on its network at a realistic, varying speed; once a second it takes a
noisy GPS fix and feeds it to its own honest-client core (`Player`), which decides what to publish. Nothing here
touches a socket: the caller moves the messages.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field

import numpy as np

from entitynet.client import Player, entity_type
from entitynet.client.network import DirEdge, NetView
from entitynet.protocol import Publish, Unpublish

#: (cruise speed m/s, speed variation) per entity type for the demo's simple kinematics
SPEEDS = {"pedestrian": (1.35, 0.25), "car": (9.0, 0.35), "bus": (7.0, 0.3), "tram": (7.0, 0.3)}


@dataclass
class Trajectory:
    """A mover's true position: distance `s` along a growing list of directed edges."""

    net: NetView
    networks: int
    rng: random.Random
    path: list[DirEdge] = field(default_factory=list)
    lengths: list[float] = field(default_factory=list)
    s: float = 0.0  # distance travelled along path[0] onwards
    base: float = 0.0  # distance of path[0]'s start (the path is trimmed behind the mover)

    def extend(self) -> None:
        last = self.path[-1]
        choices = self.net.choices(last, self.networks)
        if self.net.node_area[self.net.end_node(last)] >= 0 or not choices:
            nxt = (last[0], -last[1])  # dead end or area: turn back
        else:
            nxt = choices[self.rng.randrange(len(choices))]
        self.path.append(nxt)
        self.lengths.append(self.net.edge_len[nxt[0]])

    def advance(self, ds: float) -> None:
        self.s += max(ds, 0.0)
        while self.s - self.base > sum(self.lengths) - 1e-9:
            self.extend()
        while len(self.path) > 1 and self.s - self.base > self.lengths[0]:
            self.base += self.lengths.pop(0)
            self.path.pop(0)

    def position(self) -> tuple[float, float]:
        edge, d = self.path[0]
        local = min(self.s - self.base, self.lengths[0])
        return self.net.point(edge, local if d > 0 else self.lengths[0] - local)


def random_start(net: NetView, networks: int, rng: random.Random) -> DirEdge:
    candidates = [e for e in range(net.n_edges) if net.edge_net[e] & networks and net.edge_len[e] > 5.0]
    if not candidates:
        raise ValueError("the map has no edge of this entity type's network")
    return candidates[rng.randrange(len(candidates))], rng.choice((1, -1))


class Mover:
    """One simulated entity: trajectory + GPS noise + its Player (the honest client core)."""

    def __init__(self, topo, net: NetView, entity: int, etype: str, rng: random.Random, gps_sigma: float = 5.0):
        self.entity = entity
        self.etype = entity_type(etype)
        self.rng = rng
        self.np_rng = np.random.default_rng(rng.randrange(2**32))
        self.gps_sigma = gps_sigma
        start = random_start(net, self.etype.networks, rng)
        self.traj = Trajectory(net, self.etype.networks, rng, [start], [net.edge_len[start[0]]])
        self.traj.s = rng.uniform(0.0, net.edge_len[start[0]])
        self.traj.base = 0.0
        cruise, vary = SPEEDS.get(self.etype.name, (1.35, 0.25))
        self.cruise = cruise * rng.uniform(1.0 - vary, 1.0 + vary)
        self.speed = self.cruise
        self.pause_left = 0.0
        self.player = Player(topo, entity, self.etype, accuracy=gps_sigma)

    def step(self, dt: float) -> None:
        """Move the true position by dt seconds: speed drifts around cruise; now and then a stop."""
        if self.pause_left > 0:
            self.pause_left -= dt
            return
        if self.rng.random() < dt / 120.0:  # about one stop every two minutes (signals, shops, traffic)
            self.pause_left = self.rng.uniform(5.0, 30.0)
            return
        target = self.cruise * self.rng.uniform(0.85, 1.15)
        self.speed += (target - self.speed) * min(1.0, dt / 5.0)
        self.traj.advance(self.speed * dt)

    def fix(self, now: float) -> list[Publish | Unpublish]:
        """A noisy GPS fix of the true position, through the client core: the messages it wants sent."""
        x, y = self.traj.position()
        nx, ny = self.np_rng.normal(0.0, self.gps_sigma / math.sqrt(2.0), size=2)
        return self.player.feed(x + float(nx), y + float(ny), now, self.gps_sigma)

    def tick(self, now: float) -> list[Publish]:
        return self.player.tick(now)

    def true_xy(self) -> tuple[float, float]:
        return self.traj.position()
