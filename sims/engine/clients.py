"""Honest clients for the simulated entities: GPS fixes of the truth through each entity's own client core.

Why through `Player` and not the truth: the simulation measures what a viewer sees of *honest clients*, so
every entity takes noisy fixes (default 5 m at 1 Hz) and lets the client core decide what to publish, exactly as
a phone or a proxy would. Entities are multiplexed over a few connections as a proxy carries a fleet (entity id
modulo the connection count); the wire id of an entity is its simulation id (local ids on a connection).
Fixes are staggered over the fix interval by entity id so that a tick does not carry every fix at once; the
client cores' timers (validity expiry, heartbeat) run every tick.

Every entity's client core is stepped through the one fleet core, `entitynet.client.fleet.FleetCore`.
`core="fleet"` (the default) lets it take the usual fix and the timers over arrays, the entity's own `Player`
only where something happens; `core="player"` turns the arrays off (`vectorised=False`: one `Player.feed` /
`tick` per entity and tick, the per-entity baseline `bench sim` compares with). The messages are the same,
message for message (tests/sims/engine/test_fleet_core.py).

GPS noise per entity: a fix's noise is a function of (the run's seed, the entity's id, the fix's time) only
(`sims.mobility.gps.entity_gps`, counter-based, drawn for a whole tick's due fixes at once), not of a generator
shared by the fleet. So a worker that runs a share of the entities (`sims.workers`) takes the same fixes as the
run in one process, and a run over N workers gives the one-process report.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from entitynet import protocol as P
from entitynet.client import Player
from entitynet.client.fleet import FleetCore
from sims.engine.positions import positions
from sims.engine.route_table import route_table_of
from sims.engine.source import Body, Truth
from sims.engine.truth_arrays import EdgeArrays
from sims.mobility.gps import GPS_SIGMA, entity_gps


class Fleet:
    """Every live entity's `Player`; `step(now)` returns the messages to send, one list per connection."""

    def __init__(self, world: Truth, connections: int = 4, *, fix_interval: float = 1.0,
                 gps_sigma: float = GPS_SIGMA, seed: int = 1, threshold: float | None = None,
                 shards: int = 1, shard_at: Callable[[float, float], int] | None = None, core: str = "fleet",
                 model: str = "network"):
        """`model`: the client cores' model ("network": dead reckoning; "periodic": a standing position every
        `fix_interval`, the 1 Hz baseline)."""
        if core not in ("fleet", "player"):
            raise ValueError(f"core must be 'fleet' or 'player', got {core!r}")
        if connections < 1:
            raise ValueError(f"at least one connection, got {connections}")
        if not fix_interval > 0.0:
            raise ValueError(f"the fix interval must be > 0, got {fix_interval}")
        if shards < 1 or (shards > 1 and shard_at is None):
            raise ValueError(f"{shards} shards need a shard_at(x, y) locator")
        self.world = world
        self.per_shard = connections
        self.connections = connections * shards  # `connections` to each shard, shard-major
        self.shard_at = shard_at
        self.home: dict[int, int] = {}  # entity -> its connection, when chosen by where it starts (shards)
        self.fix_interval = fix_interval
        self.gps_sigma = gps_sigma
        self.threshold = threshold  # the client core's drift threshold (None: its default, the GPS accuracy)
        self.model = model
        self.seed = seed  # with the entity id and the fix's time, the one source of a fix's noise
        self.players: dict[int, Player] = {}
        self.next_fix: dict[int, float] = {}
        self.counters = {"fixes": 0, "rejected_fixes": 0, "published": 0, "unpublished": 0}
        self.core = core
        self.fleet_core = FleetCore(vectorised=core == "fleet")
        self._slot: dict[int, int] = {}  # entity -> its slot in the fleet core
        self._aid: list[int] = []  # slot -> entity
        self._due = np.zeros(0)  # next fix time per slot (inf: removed)
        self._edges: EdgeArrays | None = None  # the map's edge geometry as arrays, for `positions` (built once)

    def conn_of(self, entity: int) -> int:
        """The publisher connection carrying `entity`: id modulo the connection count (as a proxy splits a
        fleet), among the connections to the shard whose region the entity started in when there are shards."""
        home = self.home.get(entity)
        return entity % self.connections if home is None else home

    def add(self, a: Body) -> None:
        """Give a new entity its client core. Scheduled vehicles get their route and stops a priori; the first fix
        is phased by id (golden ratio) so fixes spread over the interval instead of all landing on one tick."""
        route, stops = (), ()
        if a.stops or a.label:  # a scheduled vehicle knows its route and stops a priori
            route = a.route.edges
            stops = [a.route.edge_offset(st.s) for st in a.stops]
        # a source may give an entity its own body (a SUMO tram's length as its parts): `etype` over the name
        etype = getattr(a, "etype", None) or a.name
        self.players[a.id] = Player(self.world.topo, a.id, etype, accuracy=self.gps_sigma, route=route,
                                    stops=stops, threshold=self.threshold, model=self.model,
                                    period=self.fix_interval)
        if self.shard_at is not None:  # by where it is: its first PUBLISH then needs no REDIRECT
            x, y = a.xy()
            self.home[a.id] = self.shard_at(float(x), float(y)) * self.per_shard + a.id % self.per_shard
        phase = (a.id * 0.618033988749895) % 1.0
        self.next_fix[a.id] = self.world.now + phase * self.fix_interval
        slot = self._slot[a.id] = self.fleet_core.add(self.players[a.id])  # (a removed entity's slot, or new)
        if slot == len(self._aid):
            self._aid.append(a.id)
        else:
            self._aid[slot] = a.id
        if slot >= len(self._due):
            self._due = np.concatenate([self._due, np.full(max(64, len(self._due)), np.inf)])
        self._due[slot] = self.next_fix[a.id]

    def step(self, now: float) -> list[list[P.Publish | P.Unpublish]]:
        """One tick: UNPUBLISH the removed entities, take the due GPS fixes through the client core and run the
        others' timers (so validity renewals are not held back to the next fix); messages per connection."""
        out: list[list[P.Publish | P.Unpublish]] = [[] for _ in range(self.connections)]
        core = self.fleet_core
        for aid, _why in self.world.take_removed():
            self.players.pop(aid, None)
            self.next_fix.pop(aid, None)
            slot = self._slot.pop(aid, None)
            if slot is not None:
                self._due[slot] = np.inf
                msgs = core.remove(slot)
                self.counters["unpublished"] += len(msgs)
                out[self.conn_of(aid)].extend(msgs)
        n = len(self._aid)
        due = self._due[:n]
        slots = np.flatnonzero(due <= now)
        slots = slots[np.argsort(core.order[slots], kind="stable")]  # in the order the entities came (the messages')
        agents = self.world.agents
        have, idle, bodies = [], [], []
        for s in slots.tolist():
            a = agents.get(self._aid[s])
            if a is None:
                idle.append(s)  # as `step`: no fix and no timers for an entity whose truth is gone
            else:
                have.append(s)
                bodies.append(a)
        fix_slots = np.array(have, dtype=np.int64)
        if len(fix_slots):
            d = due[fix_slots]
            fi = self.fix_interval
            due[fix_slots] = d + fi * np.maximum(1.0, np.floor((now - d) / fi) + 1.0)
            for s in have:
                self.next_fix[self._aid[s]] = float(due[s])
            ids = np.array([self._aid[s] for s in have], dtype=np.int64)
            if self._edges is None:
                self._edges = EdgeArrays(self.world.net)
            xy = positions(bodies, self._edges, route_table_of(self.world))
            fixes = entity_gps(xy, self.seed, ids, np.full(len(have), now), self.gps_sigma)
        else:
            fixes = np.zeros((0, 2))
        self.counters["fixes"] += len(have)
        results, rejected = core.step(now, fix_slots, fixes[:, 0], fixes[:, 1], self.gps_sigma, idle)
        self.counters["rejected_fixes"] += rejected
        aids = self._aid
        for s, msgs in results:
            box = out[self.conn_of(aids[s])]
            for m in msgs:
                box.append(m)
                self.counters["published" if isinstance(m, P.Publish) else "unpublished"] += 1
        return out
