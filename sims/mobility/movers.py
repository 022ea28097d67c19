"""Live movers: an entity that moves on the network in steps, takes GPS fixes and decides through its own
honest-client core what to publish.

Why a stepped mover next to the sampled profiles: an open-ended run (the demo, a load simulation) cannot draw
its truth up front, so a mover keeps its state and is advanced by the caller's clock. Nothing here touches a
socket: the caller moves the messages.
"""

from __future__ import annotations

import random

import numpy as np

from entitynet.client import Player
from entitynet.client.network import NetView
from entitynet.protocol import Publish, Unpublish
from sims.mobility.gps import GPS_SIGMA, gps
from sims.mobility.kinds import kind
from sims.mobility.network import Trajectory, random_start


class Mover:
    """One simulated entity: a trajectory on its kind's networks, a speed that drifts around the mover's own
    cruise with random stops, GPS noise, and its `Player` (the client core)."""

    def __init__(self, topo, net: NetView, entity: int, etype: str, rng: random.Random,
                 gps_sigma: float = GPS_SIGMA):
        self.entity = entity
        self.kind = kind(etype)
        self.etype = self.kind.etype
        self.rng = rng
        self.np_rng = np.random.default_rng(rng.randrange(2**32))
        self.gps_sigma = gps_sigma
        start = random_start(net, self.etype.networks, rng)
        self.traj = Trajectory.starting_at(net, self.etype.networks, rng, start)
        self.traj.s = rng.uniform(0.0, net.edge_len[start[0]])
        self.cruise = self.kind.cruise * rng.uniform(1.0 - self.kind.spread, 1.0 + self.kind.spread)
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
        fx, fy = gps(np.array(self.traj.position()), self.np_rng, self.gps_sigma)
        return self.player.feed(float(fx), float(fy), now, self.gps_sigma)

    def tick(self, now: float) -> list[Publish]:
        """The client core's timers (validity expiry, heartbeat) between fixes."""
        return self.player.tick(now)
