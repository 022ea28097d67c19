"""The publish's cover, compiled against Python, in one process: what `publish_cost` cannot separate (issue 22).

Why a command: on the shared 2-core machine two runs of `publish_cost` differ by 20-30 % under the same load,
far more than one compiled part changes. Here the run is publish_cost's (`Sim` of `--entities` entities on the
bundled map, the fleet core, `--warmup` simulated seconds, then `--seconds` more), and every
`Coverage.occupation` a publish makes is made by the compiled cover (`_cover.pyx`) or by the Python method (both
over the same compiled `occupy` and lateral queries), chosen at random per call and timed as the publish makes
it (`time.thread_time_ns`: cold, the entity's objects and the map's tables not yet in cache); then the other one
is made, untimed, so that the memos both use stay alike, and then the first one once more, timed (`again`: the
same call with everything it reads in cache). So the machine's load falls on both alike, and the gap between
`cold` and `again` shows what the reads of memory cost.

`python -m sims.bench.publish_ab [--entities 2000] [--warmup 20] [--seconds 20] [--seed 1] [--out FILE.json]`
"""

from __future__ import annotations

import random
import statistics
import time


def measure(entities: int = 2000, warmup: int = 20, seconds: int = 20, seed: int = 1) -> dict:
    """The cover's CPU us per call (mean, median) compiled and in Python, cold and again at once."""
    from entitynet.client import coverage
    from entitynet.topology_cache import bundled_topology
    from sims.engine.sim import Sim, SimConfig

    if not (0 < entities <= 100_000 and 0 <= warmup <= 3600 and 0 < seconds <= 3600):
        raise ValueError("entities in (0, 100000], warmup in [0, 3600], seconds in (0, 3600]")
    compiled = coverage._network_occupation
    if compiled is None:
        raise RuntimeError("the compiled cover is not built here (or ENTITYNET_PURE_PYTHON is set)")
    topo, _path = bundled_topology()
    sim = Sim(topo, SimConfig(entities=entities, viewers=0, transit=False, tick_hz=1.0, seed=5, core="fleet"))
    sim.start()
    for _ in range(warmup):
        sim.step()
    inner = coverage.Coverage.occupation
    clock = time.thread_time_ns
    rng = random.Random(seed)
    cold: dict[bool, list[int]] = {True: [], False: []}
    again: dict[bool, list[int]] = {True: [], False: []}

    def timed(self, *args):
        first = rng.random() < 0.5
        coverage._network_occupation = compiled if first else None
        t0 = clock()
        out = inner(self, *args)
        cold[first].append(clock() - t0)
        coverage._network_occupation = None if first else compiled
        inner(self, *args)
        coverage._network_occupation = compiled if first else None
        t0 = clock()
        inner(self, *args)
        again[first].append(clock() - t0)
        coverage._network_occupation = compiled
        return out

    coverage.Coverage.occupation = timed  # type: ignore[method-assign]
    try:
        for _ in range(seconds):
            for a in sim.source.step(sim.dt):
                sim.fleet.add(a)
            sim.fleet.step(sim.now)
    finally:
        coverage.Coverage.occupation = inner  # type: ignore[method-assign]
        coverage._network_occupation = compiled

    def us(xs: list[int]) -> dict:
        return {"calls": len(xs), "mean_us": statistics.mean(xs) / 1000.0 if xs else float("nan"),
                "median_us": statistics.median(xs) / 1000.0 if xs else float("nan")}

    return {"entities": entities, "warmup_s": warmup, "seconds": seconds, "seed": seed,
            "compiled": {"cold": us(cold[True]), "again": us(again[True])},
            "python": {"cold": us(cold[False]), "again": us(again[False])}}


def main(argv: list[str] | None = None) -> None:
    """The command: one measurement, printed as JSON (and written to `--out`)."""
    from sims.bench.publish_cost import command

    command(measure, __doc__.splitlines()[0], argv, 20, 1)


if __name__ == "__main__":
    main()
