"""Viewers: cameras that move at street level or above the roofs, subscribe by their view cell's PVS (or a
distance cut) through the client library, and keep ghosts of what they receive.

Sans-IO: `move(dt)` returns the SUBSCRIBE differences to send, `receive(msg, now)` takes what arrived; the
caller (the in-process switch or the trio shell) moves the messages. Counters: deliveries and bytes received.

Measured and counted viewers (`SimConfig.measured_viewers`): a measured viewer keeps ghosts (a column of the
ghost table) and enters the truth figures; a counted one moves, subscribes, is sent and reads every byte as a
measured one does (the server's load is the same), but only counts its UPDATEs, LEAVEs and bytes. Why: at
10,000 entities and 1,000 viewers a run delivers about 330,000 UPDATEs per 0.5 s tick, and keeping every
viewer's ghosts and measuring them is most of the simulation's process's work per delivery
(docs/simulation.md), while the truth figures need only a sample of the viewers.
"""

from __future__ import annotations

import random
from collections.abc import Callable

import numpy as np

from entitynet import protocol as P
from entitynet.client import GhostStore, Subscriptions
from entitynet.client.ghost_table import GhostTable
from entitynet.client.motion import Model
from entitynet.client.network import NetView
from sims.mobility import Trajectory, random_start
from topology.raw import PEDESTRIAN

CellsAt = Callable[[float, float, float], np.ndarray]


def radius_cells_at(topo, radius: float = 500.0) -> CellsAt:
    """Every cell any part of whose footprint lies within `radius` metres (horizontally) of the camera: the
    comparison's baseline. Measured as the PVS measures its own range (footprint distance, `topology.pvs`), so
    both sides count the same cells; by footprint centres the disc left out the long cells reaching into it
    (about 5 % of them on the bundled map) and the radius viewer's entities on them.

    Bounding boxes decide most cells (wholly within, or not even near); only the cells whose box straddles the
    circle are measured exactly (shapely), so a call stays well under a millisecond."""
    import shapely

    polys = topo.cell_footprints.to_shapely()
    b = topo.cell_footprints.bounds()
    x0, y0, x1, y1 = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    r2 = radius * radius

    def cells_at(x: float, y: float, z: float) -> np.ndarray:
        nx = np.maximum(np.maximum(x0 - x, x - x1), 0.0)
        ny = np.maximum(np.maximum(y0 - y, y - y1), 0.0)
        near = nx * nx + ny * ny <= r2  # the box comes within the radius
        fx = np.maximum(np.abs(x - x0), np.abs(x - x1))
        fy = np.maximum(np.abs(y - y0), np.abs(y - y1))
        ok = near & (fx * fx + fy * fy <= r2)  # the whole box is within: so is the footprint
        edge = np.flatnonzero(near & ~ok)
        if len(edge):
            ok[edge] = shapely.dwithin(polys[edge], shapely.Point(x, y), radius)
        return np.flatnonzero(ok)

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

    def __init__(self, net: NetView, index: int, high: bool, cells_at: CellsAt, rng: random.Random,
                 decoder: Callable[[bytes], Model] | None = None, table: GhostTable | None = None,
                 counted: bool = False):
        """`table`: the ghost table its store is a column of (the simulation's viewers share one, which decodes
        with the shared caching decoder, `sims.engine.decode_cache`); else `decoder`: its own store's decoder
        (default: each decodes its own). `counted`: a counted viewer (the module docstring): no ghosts
        (`ghosts` is None), only the counters."""
        self.index = index
        self.high = high
        self.z = rng.uniform(40.0, 90.0) if high else 1.7
        self.traj = Trajectory.starting_at(net, PEDESTRIAN, rng, random_start(net, PEDESTRIAN, rng))
        self.speed = 6.0 if high else 1.4
        self.subs = Subscriptions(cells_at)
        self._cells_at = cells_at
        self._last_cells: np.ndarray | None = None  # the lookup's answer at the last move
        self.lookups_skipped = 0
        self.counted = counted
        self.ghosts = None if counted else GhostStore(net, decoder=decoder, table=table)
        self.deliveries = 0
        self.leaves = 0
        self.bytes = 0

    def move(self, dt: float) -> list[P.Subscribe]:
        """Move the camera by `dt` seconds of its walk or flight; the SUBSCRIBE differences to send (and the
        ghost store told which cells are visible now, which decides the ghosts it shows). Why the identity
        test: the PVS index answers a view cell with the same cached array, and a street-level camera stays
        in one view cell for many ticks, so the subscription difference and the visible set (rebuilt from
        hundreds of cells) are skipped when the lookup returns the very array it returned last time."""
        self.traj.advance(self.speed * dt)
        x, y = self.traj.position()
        cells = self._cells_at(x, y, self.z)
        if cells is self._last_cells:  # the same view cell's PVS array (cached, read-only): nothing changed
            self.lookups_skipped += 1
            return []
        msgs = self.subs.move_camera(x, y, self.z)
        if self.ghosts is not None:
            self.ghosts.set_visible(self.subs.cells)
        self._last_cells = cells
        return msgs

    def receive_frame(self, msgs: list[P.Update | P.Leave], now: float, size: int, decoded: bool = False) -> None:
        """A whole frame of UPDATEs and LEAVEs that arrived (`size`: their encoded bytes): what `receive` does
        with each, taken by the ghost table in one call (the viewer fleet's path, `sims.engine.viewer_fleet`;
        `decoded`: the codec's messages, see `GhostTable.receive`). A counted viewer only counts them."""
        if self.ghosts is None:
            leaves = sum(type(m) is P.Leave for m in msgs)
        else:
            leaves = self.ghosts.table.receive(self.ghosts.col, msgs, now, decoded)
        self.bytes += size
        self.deliveries += len(msgs) - leaves
        self.leaves += leaves

    def receive(self, msg: P.Message, now: float, size: int = 0) -> None:
        """Count and apply a message that arrived. A WELCOME clears the ghosts (entity ids are per server
        session, so after a reconnect the old ones mean nothing) and adopts the server's limits (the next move
        subscribes within its max_subscriptions: a SUBSCRIBE over the limit is refused whole)."""
        self.bytes += size
        gs = self.ghosts
        if isinstance(msg, P.Update):
            self.deliveries += 1
            if gs is not None:
                gs.receive(msg, now)
        elif isinstance(msg, P.Leave):
            self.leaves += 1
            if gs is not None:
                gs.receive(msg, now)
        elif isinstance(msg, P.Welcome):
            if gs is not None:
                gs.clear()  # entity ids are per server session
            self.subs.apply_limits(msg.limits)
            self._last_cells = None  # the next move recomputes its subscription under the new limits


def measured_indices(viewers: int, measured: int | None) -> frozenset[int]:
    """The indices of the measured viewers out of `viewers` (None: all): `measured` spread evenly over the
    list, so that street and roof viewers (the first `roof_share` of the list) are sampled in proportion."""
    if measured is None or measured >= viewers:
        return frozenset(range(viewers))
    return frozenset(j * viewers // measured for j in range(measured))


def viewer_counts(viewers: list[SimViewer]) -> dict[str, int]:
    """A report's `viewers` counters (summed over viewer processes): street and roof viewers, how many were
    measured and how many counted, and their UPDATEs, LEAVEs and bytes received."""
    return {"street": sum(not x.high for x in viewers), "roof": sum(x.high for x in viewers),
            "measured": sum(not x.counted for x in viewers), "counted": sum(x.counted for x in viewers),
            "deliveries": sum(x.deliveries for x in viewers), "leaves": sum(x.leaves for x in viewers),
            "bytes": sum(x.bytes for x in viewers)}
