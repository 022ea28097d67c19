"""Who is on the map: a target population of pedestrians and cars on random OD trips, and the scheduled
trams and buses.

Why a target population rather than open-ended arrival rates by default: a load run is specified by how many
entities it carries (`--entities N`), so an entity that arrives or is deleted is replaced by a new trip at once;
`rates` (entities per second per type) add arrivals on top when a caller wants the reference's spawn rates.
A run that starts mid-day places the transit vehicles already under way along their routes.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

from sims.engine.agents import Agent
from sims.engine.routes import Route, Router
from sims.engine.schedule import Departure, Schedule
from sims.engine.world import World
from sims.mobility.kinds import kind
from topology.raw import PEDESTRIAN, VEHICLE


@dataclass
class PopulationConfig:
    """What `Population` keeps on the map; checked on creation so a bad share or rate is a clear
    ValueError, not a silently empty or overfull city."""

    entities: int = 300  # pedestrians and cars kept on the map
    car_share: float = 0.3
    rates: dict[str, float] = field(default_factory=dict)  # extra arrivals per second, by type
    transit: bool = True
    area_share: float = 0.2  # pedestrians whose trip ends with a walk inside a square or park
    area_walk: tuple[float, float] = (60.0, 300.0)  # seconds of that walk

    def __post_init__(self) -> None:
        if self.entities < 0:
            raise ValueError(f"entities must be >= 0, got {self.entities}")
        if not 0.0 <= self.car_share <= 1.0:
            raise ValueError(f"car share must be within 0..1, got {self.car_share}")
        for k, r in self.rates.items():
            if k not in ("pedestrian", "car") or not r >= 0.0:
                raise ValueError(f"bad spawn rate {k}={r} (pedestrian and car rates >= 0)")


class Population:
    """Spawns into a `World`: `start()` once, then `step()` after each world step."""

    def __init__(self, world: World, config: PopulationConfig, schedule: Schedule | None = None):
        self.world = world
        self.config = config
        self.schedule = schedule if config.transit else None
        self.rng = random.Random(world.rng.randrange(2**32))
        self.routers = {"pedestrian": Router(world.net, PEDESTRIAN, self.rng),
                        "car": Router(world.net, VEHICLE, self.rng)}
        net = world.net
        self.area_nodes = [n for n in net.area_node if any(net.edge_net[e] & PEDESTRIAN for e in net.node_edges[n])]
        self.trips: set[int] = set()  # ids of the OD-trip entities (the target population)
        self.transit: dict[int, str] = {}
        self._last = world.now
        self._owed: dict[str, float] = {}

    def start(self) -> list[Agent]:
        """The first population: OD trips placed part way along, and the transit vehicles under way."""
        out = [self._trip(self._type(), mid=True) for _ in range(self.config.entities)]
        if self.schedule is not None:
            now = self.world.now
            for d in self.schedule.running_at(now, 3600.0):
                a = self._depart(d, now - d.time)
                if a is not None:
                    out.append(a)
        self._last = self.world.now
        return out

    def step(self) -> list[Agent]:
        """Replace the trips that ended, add rate arrivals, and the departures due since the last call."""
        w = self.world
        out: list[Agent] = []
        self.trips &= set(w.agents)
        for tid in [t for t in self.transit if t not in w.agents]:
            del self.transit[tid]
        while len(self.trips) < self.config.entities:
            out.append(self._trip(self._type()))
        dt = w.now - self._last
        for name, rate in self.config.rates.items():
            self._owed[name] = self._owed.get(name, 0.0) + rate * dt
            while self._owed[name] >= 1.0:
                self._owed[name] -= 1.0
                a = self._trip(name)
                self.trips.discard(a.id)  # rate arrivals are extra: not replaced when they end
                out.append(a)
        if self.schedule is not None:
            for d in self.schedule.due(self._last, w.now):
                a = self._depart(d, w.now - d.time)
                if a is not None:
                    out.append(a)
        self._last = w.now
        return out

    def _type(self) -> str:
        return "car" if self.rng.random() < self.config.car_share else "pedestrian"

    def _trip(self, name: str, mid: bool = False) -> Agent:
        rng = self.rng
        router = self.routers[name]
        edges, walk = None, 0.0
        if name == "pedestrian" and self.area_nodes and rng.random() < self.config.area_share:
            for _ in range(5):  # to a square or park, then a walk inside it
                start = (router.edges[rng.randrange(len(router.edges))], rng.choice((1, -1)))
                edges = router.path(start, self.area_nodes[rng.randrange(len(self.area_nodes))])
                if edges:
                    walk = rng.uniform(*self.config.area_walk)
                    break
        if not edges:
            edges = router.trip(rng)
        s = 0.0
        if mid:
            s = rng.uniform(0.0, 0.8) * Route(self.world.net, edges).length
        a = self.world.add(name, edges, s=s, area_walk=walk)
        self.trips.add(a.id)
        return a

    def _depart(self, d: Departure, late: float) -> Agent | None:
        """A departure, `late` seconds after its time: placed where its timetable puts it then (see
        `timetable_position`), or None if it would already have left the map."""
        k = kind(d.mode)
        route = Route(self.world.net, list(d.edges))
        s, dwelling = timetable_position(d.stops, max(late, 0.0), k.cruise)
        if s >= route.length - 1.0:
            return None
        stops = [st for st in d.stops if (st.s > s if dwelling else st.s >= s)]
        # standing at a stop (its terminus on the map, or dwelling); otherwise under way at its own speed: a trip
        # that enters at the map's edge drives in from outside (its spawn time counts on cruise speed there)
        standing = dwelling or (s == 0.0 and bool(d.stops) and d.stops[0].s < 1.0)
        a = self.world.add(d.mode, list(d.edges), s=s, v=0.0 if standing else None, stops=stops,
                           label=f"{d.ref} {d.trip_id}", timetable=d.time)
        self.transit[a.id] = d.trip_id
        return a


def timetable_position(stops, late: float, cruise: float) -> tuple[float, bool]:
    """Route distance of a scheduled vehicle `late` seconds after its departure, and whether it is dwelling at a
    stop then: linear between the timetable's stops (standing for each stop's dwell after its arrival), at
    `cruise` after the last one. Stops without a timetable: at cruise speed, less the dwells already passed."""
    if any(st.arrive is None for st in stops):
        s = late * cruise
        passed = sum(st.dwell for st in stops if st.s < s)
        return max(0.0, (late - passed) * cruise), False
    s0, t0 = 0.0, 0.0
    for st in stops:
        if late <= st.arrive:
            span = st.arrive - t0
            return s0 + (st.s - s0) * ((late - t0) / span if span > 0 else 1.0), False
        if late <= st.arrive + st.dwell:
            return st.s, True
        s0, t0 = st.s, st.arrive + st.dwell
    return s0 + (late - t0) * cruise, False
