"""The cluster benchmark's load: movers and viewers as real client connections, and what viewers saw.

Movers random-walk over the cell adjacency graph (a cell every `move_every` seconds on average), publish once
per `publish_interval_s` with a validity of `validity_ms`, and carry a global id in their payload, so that a
viewer can tell one entity under two server ids (a duplicate) and measure a handover: the time from the LEAVE
of the old id to the first UPDATE of the new one. Every client is an `entitynet.connection.Connection`: the
REDIRECTs and failovers are the real ones. Viewers subscribe to fixed PVS cell sets.
"""

from __future__ import annotations

import random
import struct
from dataclasses import dataclass, field

import trio

from entitynet import protocol as P
from entitynet.connection import Connection

GID = struct.Struct(">I")


def _addr(a: str) -> tuple[str, int]:
    host, port = a.rsplit(":", 1)
    return host, int(port)


@dataclass
class Mover:
    """A publishing client; `gid` travels in its payload so viewers can recognise it under any server id."""

    gid: int
    cell: int
    conn: Connection | None = None
    seq: int = 0
    redirects: int = 0


@dataclass
class Viewer:
    """A subscribing client and what it saw: duplicates (one gid under two ids) and handover gaps."""

    cells: frozenset[int]
    conn: Connection | None = None
    visible: dict[int, int] = field(default_factory=dict)  # server id -> gid
    by_gid: dict[int, set[int]] = field(default_factory=dict)
    last_leave: dict[int, tuple[int, float]] = field(default_factory=dict)  # gid -> (old id, time of its LEAVE)
    deliveries: int = 0
    duplicates: int = 0
    gaps: list[float] = field(default_factory=list)
    # gid -> (time, cell) of its mover's last REDIRECT (shared by all viewers)
    redirected_at: dict[int, tuple[float, int]] = field(default_factory=dict)
    welcomes: int = 0

    def on_message(self, m: P.Message) -> None:
        """Track visible entities by gid; a Welcome (new session) clears everything, since server ids start afresh."""
        t = type(m)
        now = trio.current_time()
        if t is P.Update:
            self.deliveries += 1
            if len(m.payload) < 4:
                return
            gid = GID.unpack_from(m.payload)[0]
            if m.entity not in self.visible:
                ids = self.by_gid.setdefault(gid, set())
                if ids:
                    self.duplicates += 1  # the same entity under two ids at once
                ids.add(m.entity)
                self.visible[m.entity] = gid
                old = self.last_leave.pop(gid, None)
                moved = self.redirected_at.get(gid)
                # a handover: the entity was in this viewer's cells when it crossed (REDIRECT), its old id left
                # here then, and its new id arrived (an entity that also walked out of view is not counted)
                if (old is not None and old[0] != m.entity and moved is not None and old[1] >= moved[0] - 0.5
                        and moved[1] in self.cells and m.cells and m.cells[0] in self.cells):
                    self.gaps.append(now - old[1])
        elif t is P.Leave:
            gid = self.visible.pop(m.entity, None)
            if gid is not None:
                ids = self.by_gid.get(gid)
                if ids is not None:
                    ids.discard(m.entity)
                    if not ids:
                        del self.by_gid[gid]
                self.last_leave[gid] = (m.entity, now)
        elif t is P.Welcome:  # a new session (redirect, failover): server ids start afresh
            self.welcomes += 1
            self.visible.clear()
            self.by_gid.clear()
            self.last_leave.clear()

    def seen(self) -> set[int]:
        """The global ids this viewer sees now (to compare with what it should see)."""
        return set(self.by_gid)


class Load:
    """Start movers and viewers against shard `addresses`; `owner(cell)` is the shard address a mover starts on."""

    def __init__(self, digest: str, addresses: list[str], owner_of_cell, adjacency: list[list[int]],
                 start_cells: list[int], view_cells: list[tuple[int, ...]], viewer_home: list[str], params: dict,
                 rng: random.Random):
        self.digest = digest
        self.addresses = addresses
        self.owner_of_cell = owner_of_cell
        self.adj = adjacency
        self.p = params
        self.rng = rng
        self.movers = [Mover(i + 1, c) for i, c in enumerate(start_cells)]
        self.redirected_at: dict[int, tuple[float, int]] = {}
        self.viewers = [Viewer(frozenset(cells), redirected_at=self.redirected_at) for cells in view_cells]
        self.viewer_home = viewer_home
        self.moving = True

    def _conn(self, home: str, on_message=None) -> Connection:
        alts = tuple(_addr(a) for a in self.addresses if a != home)
        return Connection(_addr(home), self.digest, backoff=(0.05, 0.5), ping_interval=30.0,
                          alternates=alts, failover_s=self.p["failover_s"], on_message=on_message)

    async def start(self, nursery: trio.Nursery) -> None:
        """Connect every viewer (subscribed) first, then every mover on its start cell's shard, so the first
        updates already have an audience. Each group connects concurrently: one handshake after another cost
        1-2 s of every run on a loaded machine, and the order that matters is only viewers before movers."""
        async def viewer(v: Viewer, home: str, task_status=trio.TASK_STATUS_IGNORED) -> None:
            v.conn = self._conn(home, v.on_message)
            await nursery.start(v.conn.run)
            await v.conn.set_subscription(v.cells)
            task_status.started()

        async def mover(m: Mover, task_status=trio.TASK_STATUS_IGNORED) -> None:
            m.conn = self._conn(self.owner_of_cell(m.cell), self._mover_messages(m))
            await nursery.start(m.conn.run)
            task_status.started()

        async with trio.open_nursery() as group:
            for v, home in zip(self.viewers, self.viewer_home, strict=True):
                group.start_soon(viewer, v, home)
        async with trio.open_nursery() as group:
            for m in self.movers:
                group.start_soon(mover, m)
        for m in self.movers:
            nursery.start_soon(self._move, m)

    def _mover_messages(self, m: Mover):
        def on(msg: P.Message) -> None:
            if type(msg) is P.Redirect:
                m.redirects += 1
                self.redirected_at[m.gid] = (trio.current_time(), m.cell)
        return on

    async def _move(self, m: Mover) -> None:
        p, rng = self.p, self.rng
        await trio.sleep(rng.random() * p["publish_interval_s"])
        while True:
            if self.moving and rng.random() < p["publish_interval_s"] / p["move_every_s"] and self.adj[m.cell]:
                m.cell = rng.choice(self.adj[m.cell])
            m.seq += 1
            await m.conn.publish(P.Publish(1, m.seq, (m.cell,), p["validity_ms"], GID.pack(m.gid) + b"\0" * 28))
            await trio.sleep(p["publish_interval_s"])

    # ---- figures ---------------------------------------------------------------------------------------------
    def deliveries(self) -> int:
        """UPDATEs received by all viewers so far (the denominator of the per-delivery figures)."""
        return sum(v.deliveries for v in self.viewers)

    def all_off(self, address: tuple[str, int]) -> bool:
        """Every client that was on the shard at `address` has a new home that has welcomed it."""
        conns = [m.conn for m in self.movers] + [v.conn for v in self.viewers]
        return all(c.address != address and c.session.connected for c in conns)

    def missing_and_doubled(self) -> tuple[int, int]:
        """Entities a viewer should see (their cell is in its subscription) but does not, and entities shown
        under two ids right now, over all viewers."""
        where: dict[int, int] = {m.gid: m.cell for m in self.movers}
        missing = doubled = 0
        for v in self.viewers:
            truth = {g for g, c in where.items() if c in v.cells}
            missing += len(truth - v.seen())
            doubled += sum(1 for ids in v.by_gid.values() if len(ids) > 1)
        return missing, doubled
