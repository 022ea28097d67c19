"""The whole simulation as one sans-IO core: world, population, honest clients, viewers and measurement.

Why one core for every driver: the CLI over real sockets (`sims.shell`), the in-process switchboard used by
tests and the benchmark (`sims.engine.local`) and any other shell drive the same object: `start()` then
`step()` once per tick, each returning the messages to send (per publisher connection, per viewer); the
driver hands what arrives to `deliver(viewer, msg, size)`. Time is the world's clock (seconds since the
service day's midnight, so the schedule and the clients agree); the driver decides how fast it runs.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from entitynet import protocol as P
from entitynet.client.ghost_table import GhostTable
from sims.engine import TICK_HZ_RANGE
from sims.engine.clients import Fleet
from sims.engine.decode_cache import DecodeCache
from sims.engine.measure import Measure
from sims.engine.schedule import Schedule
from sims.engine.source import MobilitySource, OurWorld
from sims.engine.viewers import CellsAt, SimViewer, measured_indices, pvs_cells_at, radius_cells_at, viewer_counts


@dataclass
class SimConfig:
    """A run's settings; checked on creation so a bad value is one clear ValueError listing every problem
    (the CLI turns it into a usage error) before anything is built."""

    entities: int = 300
    viewers: int = 24
    connections: int = 4
    car_share: float = 0.3
    roof_share: float = 0.25
    tick_hz: float = 2.0
    fix_interval: float = 1.0
    gps_sigma: float = 5.0
    seed: int = 1
    start: float = 8 * 3600.0  # service-day seconds
    transit: bool = True
    subscribe: str = "pvs"  # or "radius"
    radius: float = 500.0
    sample_every: float = 1.0
    #: the share of viewers measured at each sample, taken in turn (1.0: every viewer, the full measure). Why:
    #: a sample costs about viewers x visible entities, one burst per `sample_every` that made real-time runs
    #: late; 0.1 measures a tenth of the viewers each second, so each viewer every 10 s (counts shrink, the
    #: fractions and percentiles estimate the same figures). The deterministic runs keep 1.0.
    measure_share: float = 1.0
    #: how many viewers keep ghosts and enter the truth figures (None: all); the others are counted viewers,
    #: which connect, subscribe and read every byte but only count it (`sims.engine.viewers`). Why: the server's
    #: load is the full run's while the simulation's process keeps and measures only a sample
    measured_viewers: int | None = None
    measure_after: float = 2.0  # s: the start, when every entity appears at once before its first fix, is not sampled
    threshold: float | None = None  # the client core's drift threshold (None: its default)
    core: str = "fleet"  # the honest clients' core: "fleet" (vectorised, the same messages) or "player"
    #: the honest clients' model: "network" (dead reckoning on the street network) or "periodic" (a standing
    #: position every fix interval: the ablation `bench e2e` compares with)
    client_model: str = "network"

    def __post_init__(self) -> None:
        problems = []
        if self.viewers < 0:
            problems.append(f"viewers must be >= 0, got {self.viewers}")
        if self.connections < 1:
            problems.append(f"connections must be >= 1, got {self.connections}")
        if not TICK_HZ_RANGE[0] <= self.tick_hz <= TICK_HZ_RANGE[1]:
            lo, hi = TICK_HZ_RANGE
            problems.append(f"tick rate must be within {lo:g}..{hi:g} Hz, got {self.tick_hz}")
        if not self.fix_interval > 0:
            problems.append(f"fix interval must be > 0, got {self.fix_interval}")
        if not self.gps_sigma > 0:  # the client core refuses fixes that claim no error at all
            problems.append(f"GPS noise must be > 0 m, got {self.gps_sigma}")
        if not 0.0 <= self.roof_share <= 1.0:
            problems.append(f"roof share must be within 0..1, got {self.roof_share}")
        if self.subscribe not in ("pvs", "radius"):
            problems.append(f"subscribe by 'pvs' or 'radius', got {self.subscribe!r}")
        if not self.radius > 0:
            problems.append(f"radius must be > 0, got {self.radius}")
        if not 0.0 < self.measure_share <= 1.0:
            problems.append(f"measure share must be within (0, 1], got {self.measure_share}")
        if self.measured_viewers is not None and not 1 <= self.measured_viewers <= max(self.viewers, 1):
            problems.append(f"measured viewers must be between 1 and the {self.viewers} viewers, "
                            f"got {self.measured_viewers}")
        if self.core not in ("fleet", "player"):
            problems.append(f"core must be 'fleet' or 'player', got {self.core!r}")
        if self.client_model not in ("network", "periodic"):
            problems.append(f"client model must be 'network' or 'periodic', got {self.client_model!r}")
        if problems:
            raise ValueError("; ".join(problems))


class Sim:
    """The whole simulation as one sans-IO core (see the module docstring): every driver calls `start()`, then
    `step()` per tick, hands arrivals to `deliver` and calls `maybe_sample`. The truth comes from a mobility
    source (`sims.engine.source`): our own world by default, or `source` (a SUMO scenario) when given."""

    def __init__(self, topo, config: SimConfig, schedule: Schedule | None = None, cells_at: CellsAt | None = None,
                 shards: int = 1, shard_at: Callable[[float, float], int] | None = None,
                 source: MobilitySource | None = None):
        self.topo = topo
        self.config = config
        if source is None:
            source = OurWorld(topo, config.seed, config.start, config.entities, config.car_share, config.transit,
                              schedule)
        self.source = source
        self.world = source.world  # the truth: live entities, clock, counters
        self.population = getattr(source, "population", None)  # our world's spawner (None for other sources)
        self.fleet = Fleet(self.world, config.connections, fix_interval=config.fix_interval,
                           gps_sigma=config.gps_sigma, seed=config.seed, threshold=config.threshold,
                           shards=shards, shard_at=shard_at,  # shards: `connections` to each, by where entities are
                           core=config.core, model=config.client_model)
        #: how the viewers subscribe: "pvs", or "radius" (asked for, or the map has no PVS to subscribe by)
        self.subscribe_by = config.subscribe
        if cells_at is None:
            cells_at = pvs_cells_at(topo) if config.subscribe == "pvs" else None
            if cells_at is None:
                cells_at = radius_cells_at(topo, config.radius)
                self.subscribe_by = "radius"
        rng = random.Random(config.seed + 7)
        n_high = round(config.viewers * config.roof_share)
        self.decode_cache = DecodeCache(self.world.net)  # one payload reaches many viewers: decode it once
        #: every viewer's ghosts in one table of arrays (the ghost rules' one home), decoding through the cache
        self.ghost_table = GhostTable(self.world.net, self.decode_cache)
        measured = measured_indices(config.viewers, config.measured_viewers)
        self.viewers = [SimViewer(self.world.net, i, i < n_high, cells_at, rng, table=self.ghost_table,
                                  counted=i not in measured) for i in range(config.viewers)]
        #: the run's measured viewers in index order: viewer index -> its rank among them (the measure's turns)
        self.measured_rank = {i: r for r, i in enumerate(sorted(measured))}
        self.measure = Measure()
        self.dt = 1.0 / config.tick_hz
        self._next_sample = config.start + config.measure_after
        self._measure_from = 0  # the next viewer measured when measure_share < 1
        self.ticks = 0

    @property
    def now(self) -> float:
        """The world's clock (service-day seconds): the one time base of the schedule, clients and viewers."""
        return self.world.now

    def subscription_text(self) -> str:
        """How the viewers subscribe, for the command's first line: "pvs", or "radius (500 m)", saying so when
        the PVS was asked for and the map has none (a user must not read "pvs" for a run that used the radius)."""
        if self.subscribe_by == "pvs":
            return "pvs"
        why = ": the map has no PVS" if self.config.subscribe == "pvs" else ""
        return f"radius ({self.config.radius:g} m{why})"

    def start(self) -> tuple[list[list[P.Message]], list[list[P.Subscribe]]]:
        """The first population and the viewers' first subscriptions: the messages to send before the first tick."""
        for a in self.source.start():
            self.fleet.add(a)
        return self.fleet.step(self.now), [v.move(0.0) for v in self.viewers]

    def step(self) -> tuple[list[list[P.Message]], list[list[P.Subscribe]]]:
        """One tick: the truth moves, spawns happen, fixes are taken, cameras move."""
        new = self.source.step(self.dt)
        self.ticks += 1
        for a in new:
            self.fleet.add(a)
        return self.fleet.step(self.now), [v.move(self.dt) for v in self.viewers]

    def deliver(self, viewer: int, msg: P.Message, size: int = 0) -> None:
        """A message that arrived for viewer `viewer` (`size`: its encoded bytes, for the per-viewer byte counts)."""
        self.viewers[viewer].receive(msg, self.now, size)

    def maybe_sample(self, eid_to_agent: dict[int, int] | None) -> bool:
        """Sample truth against viewers when due (and when ghost ids can be mapped back to the truth)."""
        if self.now + 1e-9 < self._next_sample:
            return False
        self._next_sample += self.config.sample_every
        viewers = self.measured_viewers() if eid_to_agent is not None else []
        if viewers:  # none (a viewer processes' coordinator, a share with none in the window): no truth read
            self.measure.sample(self.now, self.world, viewers, eid_to_agent)
        return True

    def measured_viewers(self) -> list[SimViewer]:
        """The viewers the next sample measures: every measured viewer (all of them unless
        `measured_viewers`), or with `measure_share` < 1 the next ceil(share x M) of the run's M measured ones
        in turn (wrapping round), so every one is measured equally often. A viewer process holds a share of the
        run's viewers (`sims.viewers`): it measures those of its own that fall in the run's window, so the
        processes together measure the viewers one process would, equally often."""
        rank = self.measured_rank
        v = [x for x in self.viewers if not x.counted]
        share = self.config.measure_share
        if share >= 1.0 or not v:
            return v
        n = len(rank)
        k = min(n, max(1, math.ceil(share * n - 1e-9)))
        i = self._measure_from
        self._measure_from = (i + k) % n
        if len(v) == n:
            return [v[(i + j) % n] for j in range(k)]
        return [x for x in v if (rank[x.index] - i) % n < k]

    def counts(self) -> dict:
        """The cheap counters (entities by type, collisions, spawns, client messages), for the live summary line
        without the cost of the full report."""
        w = self.world
        c = w.counters
        return {
            "entities": dict(sorted(w.by_type().items())),
            "collisions": {"avoided": c["avoided"], "accepted": c["accepted"], "deleted": c["deleted"]},
            "spawned": c["spawned"], "arrived": c["arrived"], "stops_served": c["stops_served"],
            "clients": dict(self.fleet.counters),
        }

    def report(self) -> dict:
        """The run's JSON-ready report: config, counts, viewer traffic and truth against viewers."""
        v = self.viewers
        return {
            "config": asdict(self.config),
            "mobility": self.source.report(),
            "subscribe_by": self.subscribe_by,
            "sim_time_s": self.ticks * self.dt,
            **self.counts(),
            "viewers": viewer_counts(v),
            "truth_vs_viewer": {**self.measure.summary(), "measured_viewers": len(self.measured_rank),
                                "counted_viewers": self.config.viewers - len(self.measured_rank)},
            "timetable": timetable_summary(self.world.stop_lateness),
        }


def timetable_summary(lateness: list[float]) -> dict:
    """Schedule adherence of the buses and trams: seconds after the timetable's arrival at each stop served on a
    timetable (negative: early), as median, p95 and max, and the share more than a minute late."""
    if not lateness:
        return {"stops": 0, "lateness_p50_s": None, "lateness_p95_s": None, "lateness_max_s": None,
                "late_over_60s": None}
    x = np.asarray(lateness)
    return {"stops": int(x.size), "lateness_p50_s": float(np.percentile(x, 50)),
            "lateness_p95_s": float(np.percentile(x, 95)), "lateness_max_s": float(x.max()),
            "late_over_60s": float(np.mean(x > 60.0))}
