"""Mobility sources: what produces the true position of every entity at every tick.

Why a seam here and not a second simulator: everything downstream of the truth (GPS fixes through the honest
client core, the viewers, the truth-against-viewer measure, the report and the live summary) is the same
whoever moves the entities. `Sim` asks its source for the truth (`world`), for the entities that appeared at the
start and at each step, and the source steps its own model:

- `OurWorld`: our own world model (`World`: IDM cars, pedestrians, timetabled buses and two-part trams) with its
  `Population` (OD trips kept at a target count, and the GTFS schedule's departures);
- `sims.sumo.source.SumoSource`: an Eclipse SUMO scenario stepped in process through libsumo.

The truth a source hands over (`Truth`) is what the fleet, the measure and the report read: the live entities by
id (each with `id`, `name`, `xy()`, `cells()`, `part_points()`, and `stops` / `label` / `route` for a vehicle
whose route its client knows a priori), the clock, the removals since the last call and the counters.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from typing import Any, Protocol

from sims.engine.agents import Agent
from sims.engine.population import Population, PopulationConfig
from sims.engine.schedule import Schedule
from sims.engine.world import World


class Body(Protocol):
    """One entity's truth as the fleet and the measure read it."""

    id: int
    stops: list
    label: str

    @property
    def name(self) -> str:
        """The client core's entity type name (pedestrian, car, bus, tram, cyclist)."""

    def xy(self, behind: float = 0.0) -> tuple[float, float]:
        """Local (x, y) of the front, or of the point `behind` metres behind it."""

    def cells(self) -> tuple[int, ...]:
        """The visibility cells the true body occupies now (front first)."""


class Truth(Protocol):
    """The truth a source keeps: the live entities, the clock and the counters (see the module docstring)."""

    topo: Any
    net: Any
    now: float
    agents: Mapping[int, Body]
    counters: Counter
    stop_lateness: list[float]

    def take_removed(self) -> list[tuple[int, str]]:
        """The (id, why) removed since the last call, once (the fleet sends their UNPUBLISH)."""

    def by_type(self) -> Counter:
        """Live entities counted by type name."""


class MobilitySource(Protocol):
    """Moves the entities: `start()` once, then `step(dt)` per tick; both return the entities that appeared."""

    world: Truth

    def start(self) -> list[Body]:
        """The entities on the map at the start."""

    def step(self, dt: float) -> list[Body]:
        """Advance the truth by `dt` seconds; the entities that appeared in it."""

    def report(self) -> dict:
        """The source's own section of the run's report (what it is, and what only it counts)."""

    def close(self) -> None:
        """Release what the source holds (a SUMO instance); safe to call twice."""


class OurWorld:
    """Our own world model as a mobility source: `World` stepped, `Population` spawning into it."""

    def __init__(self, topo, seed: int, start: float, entities: int, car_share: float, transit: bool,
                 schedule: Schedule | None = None):
        self.world = World(topo, seed, start=start)
        self.population = Population(self.world, PopulationConfig(entities, car_share, transit=transit), schedule)

    def start(self) -> list[Agent]:
        """The first population (OD trips part way along, transit vehicles under way)."""
        return self.population.start()

    def step(self, dt: float) -> list[Agent]:
        """The world moves by `dt`, then the population replaces ended trips and adds the due departures."""
        self.world.step(dt)
        return self.population.step()

    def report(self) -> dict:
        """Our world's section of the report: its name (its counters are the report's own)."""
        return {"source": "ours"}

    def close(self) -> None:
        """Nothing to release."""
