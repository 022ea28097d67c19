"""Schedule adherence of the simulated trams and buses: `python -m sims.bench.timetable [--entities N] [--seeds
1 2 3] [--minutes 10]` prints, per seed, the lateness at stops over a run from 08:00 on the bundled feed.

Why the truth alone (a `World` and its `Population`, stepped as `Sim.step` does, without clients or viewers):
the honest clients and viewers observe the truth and do not change it, and leaving them out makes a 10-minute
run take seconds. Figures in docs/simulation.md ("Schedule adherence").
"""

from __future__ import annotations

import argparse
import json

from sims.engine.population import Population, PopulationConfig
from sims.engine.schedule import Schedule
from sims.engine.sim import timetable_summary
from sims.engine.world import World


def adherence(topo, schedule: Schedule, *, entities: int = 300, car_share: float = 0.3, seed: int = 1,
              start: float = 8 * 3600.0, seconds: float = 600.0, tick_hz: float = 2.0) -> dict:
    """Step the truth for `seconds` from `start` and summarise the lateness at the stops served (the report's
    `timetable` section), with the collisions counted on the way."""
    w = World(topo, seed, start=start)
    pop = Population(w, PopulationConfig(entities, car_share), schedule)
    pop.start()
    dt = 1.0 / tick_hz
    for _ in range(round(seconds * tick_hz)):
        w.step(dt)
        pop.step()
    return {"seed": seed, "entities": entities, "seconds": seconds, **timetable_summary(w.stop_lateness),
            "early_over_30s": sum(x < -30.0 for x in w.stop_lateness) / max(len(w.stop_lateness), 1),
            "collisions": {k: w.counters[k] for k in ("avoided", "accepted", "deleted")}}


def main() -> None:
    """The command line: the bundled map and feed (both cached), one JSON line per seed."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--entities", type=int, default=300, help="pedestrians and cars besides the schedule")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--minutes", type=float, default=10.0)
    args = ap.parse_args()
    from entitynet.topology_cache import bundled_topology, cache_dir
    from sims.engine.schedule import BUNDLED_FEED, load_schedule

    topo, _path = bundled_topology(lambda m: None, with_pvs=True)
    for seed in args.seeds:
        schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir(), seed=seed)
        print(json.dumps(adherence(topo, schedule, entities=args.entities, seed=seed, seconds=60.0 * args.minutes)),
              flush=True)


if __name__ == "__main__":
    main()
