"""A worker's share of a run: the whole world stepped from the seed, the honest clients of its entities only.

Why the whole world on every worker: the truth of one entity depends on its neighbours (car following,
crossings, collisions), and a world cut into regions would need a border band exchanged every tick and would
still change the truth with the number of workers. Stepping all of it from the seed costs each worker the
world's step (a fraction of a run's time: most goes to the client cores, docs/simulation.md) and gives every
worker, and the coordinator, the same truth: no interaction is ever split, none is missed.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, fields

from entitynet import protocol as P
from sims.engine.clients import Fleet
from sims.engine.schedule import Schedule
from sims.engine.sim import SimConfig
from sims.engine.source import OurWorld
from sims.workers.split import Assignment


class RefusedRun(Exception):
    """A worker cannot take part in a run (another map or schedule, a config it does not know): why."""


def schedule_fingerprint(schedule: Schedule | None) -> str:
    """A short digest of the departures a schedule puts on the map: workers must spawn the same trams and
    buses as the coordinator, or the truths part at the first departure ("" for no schedule)."""
    if schedule is None:
        return ""
    h = hashlib.sha256()
    for d in schedule.departures:
        h.update(f"{d.trip_id}|{d.time:.3f}|{len(d.edges)}|{len(d.stops)};".encode())
    return h.hexdigest()[:16]


def run_digests(topo, schedule: Schedule | None) -> dict[str, str]:
    """What a worker's map and schedule must match: the topology's digest and the schedule's fingerprint."""
    return {"topology": str(topo.digest), "schedule": schedule_fingerprint(schedule)}


def config_to_wire(config: SimConfig) -> dict:
    """The run's settings as a worker receives them."""
    return asdict(config)


def _wrong_type(value, default) -> bool:
    """Whether `value` cannot stand where `SimConfig` has `default` (its fields are numbers, flags and names;
    None where the default is None, or a number there)."""
    if isinstance(default, bool):
        return not isinstance(value, bool)
    if isinstance(default, int):
        return isinstance(value, bool) or not isinstance(value, int)
    if isinstance(default, float) or default is None:
        if value is None:
            return default is not None
        return isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value)
    return not isinstance(value, type(default))


def config_from_wire(data: dict) -> SimConfig:
    """`SimConfig` from an assign frame; a setting this version does not know, or a bad value, is a refusal.
    Why the types are checked here: the frame comes from the network (any publisher on the NATS subject), and
    `SimConfig` checks ranges, not types: a string for a count failed deep inside the world's build."""
    known = {f.name: f.default for f in fields(SimConfig)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise RefusedRun(f"settings this worker does not know: {', '.join(map(str, unknown))} (another version?)")
    mistyped = sorted(k for k, v in data.items() if _wrong_type(v, known[k]))
    if mistyped:
        raise RefusedRun(f"bad run settings: {', '.join(f'{k}={data[k]!r:.40}' for k in mistyped)} (wrong type)")
    try:
        return SimConfig(**data)
    except (TypeError, ValueError) as exc:
        raise RefusedRun(f"bad run settings: {exc}") from None


class WorkerShare:
    """Worker `index` of `n`: `tick(k, dead)` steps the world to tick k and returns what its clients sent."""

    def __init__(self, topo, schedule: Schedule | None, config: SimConfig, index: int, n: int):
        if not 0 <= index < n:
            raise ValueError(f"worker {index} of {n}")
        self.index, self.n = index, n
        self.config = config
        self.source = OurWorld(topo, config.seed, config.start, config.entities, config.car_share, config.transit,
                               schedule if config.transit else None)
        self.world = self.source.world
        # one connection: the coordinator routes each message to its own connections (and shards)
        self.fleet = Fleet(self.world, 1, fix_interval=config.fix_interval, gps_sigma=config.gps_sigma,
                           seed=config.seed, threshold=config.threshold, core=config.core, model=config.client_model)
        self.assignment = Assignment(n)
        self.dt = 1.0 / config.tick_hz
        self.k = -1

    def tick(self, k: int, dead: list[int]) -> list[P.Message]:
        """Tick `k` (0: the start): apply the deaths not yet applied (adopting this worker's part of the dead
        workers' entities), step the world, give this worker's new entities their client cores, step them."""
        if k != self.k + 1:
            raise ValueError(f"tick {k} after tick {self.k}: ticks come in order")
        world = self.world
        for w in dead[len(self.assignment.dead):]:
            for e, new in self.assignment.kill(w, world.agents).items():
                if new == self.index:
                    self.fleet.add(world.agents[e])
        new_bodies = self.source.start() if k == 0 else self.source.step(self.dt)
        for a in new_bodies:
            if self.assignment.add(a.id) == self.index:
                self.fleet.add(a)
        removed = [aid for aid, _why in world.removed]  # the fleet takes them in its step
        msgs = self.fleet.step(world.now)[0]
        self.assignment.forget(removed)
        self.k = k
        return msgs

    def owned(self) -> int:
        """Live entities whose clients this worker runs."""
        return self.assignment.counts()[self.index]

    def counters(self) -> dict[str, int]:
        """The client counters of this worker's fleet (cumulative)."""
        return {k: int(v) for k, v in self.fleet.counters.items()}
