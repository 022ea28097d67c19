"""Viewers: cameras that move at street level or above the roofs, subscribe by their view cell's PVS (or a
distance cut) through the client library, and keep ghosts of what they receive.

Sans-IO: `move(dt)` returns the SUBSCRIBE differences to send, `receive(msg, now)` takes what arrived; the
caller (the in-process switch or the trio shell) moves the messages. Counters: deliveries and bytes received.
"""

from __future__ import annotations

import random
from collections.abc import Callable

import numpy as np

from entitynet import protocol as P
from entitynet.client import GhostStore, Subscriptions
from entitynet.client.network import NetView
from sims.mobility import Trajectory, random_start
from topology.raw import PEDESTRIAN

CellsAt = Callable[[float, float, float], np.ndarray]


def radius_cells_at(topo, radius: float = 500.0) -> CellsAt:
    """Every cell whose footprint centre is within `radius` metres of the camera (the comparison's baseline)."""
    b = topo.cell_footprints.bounds()
    centres = np.column_stack([(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2])

    def cells_at(x: float, y: float, z: float) -> np.ndarray:
        return np.flatnonzero(np.hypot(centres[:, 0] - x, centres[:, 1] - y) <= radius)

    return cells_at


def pvs_cells_at(topo) -> CellsAt | None:
    """The PVS lookup of the artifact, or None when it has no PVS."""
    if "pvs" not in topo.meta:
        return None
    from topology.pvs import PvsIndex

    return PvsIndex.from_topology(topo).cells_at


class SimViewer:
    """A camera walking the pedestrian network (street level, 1.7 m, 1.4 m/s) or flying over it (40-90 m up,
    6 m/s), subscribed to what `cells_at` gives for its position."""

    def __init__(self, net: NetView, index: int, high: bool, cells_at: CellsAt, rng: random.Random):
        self.index = index
        self.high = high
        self.z = rng.uniform(40.0, 90.0) if high else 1.7
        self.traj = Trajectory.starting_at(net, PEDESTRIAN, rng, random_start(net, PEDESTRIAN, rng))
        self.speed = 6.0 if high else 1.4
        self.subs = Subscriptions(cells_at)
        self.ghosts = GhostStore(net)
        self.deliveries = 0
        self.leaves = 0
        self.bytes = 0

    def move(self, dt: float) -> list[P.Subscribe]:
        """Move the camera by `dt` seconds of its walk or flight; the SUBSCRIBE differences to send (and the
        ghost store told which cells are visible now, which decides the ghosts it shows)."""
        self.traj.advance(self.speed * dt)
        x, y = self.traj.position()
        msgs = self.subs.move_camera(x, y, self.z)
        self.ghosts.set_visible(self.subs.cells)
        return msgs

    def receive(self, msg: P.Message, now: float, size: int = 0) -> None:
        """Count and apply a message that arrived. A WELCOME clears the ghosts (entity ids are per server
        session, so after a reconnect the old ones mean nothing) and adopts the server's limits (the next move
        subscribes within its max_subscriptions: a SUBSCRIBE over the limit is refused whole)."""
        self.bytes += size
        if isinstance(msg, P.Update):
            self.deliveries += 1
            self.ghosts.receive(msg, now)
        elif isinstance(msg, P.Leave):
            self.leaves += 1
            self.ghosts.receive(msg, now)
        elif isinstance(msg, P.Welcome):
            self.ghosts.ghosts.clear()  # entity ids are per server session
            self.subs.apply_limits(msg.limits)
