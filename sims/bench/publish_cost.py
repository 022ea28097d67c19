"""What one publish costs: the CPU time inside `Player._publish` in a city simulation with the fleet core (#22).

Why a command: the publish is most of a fleet fix's cost where an entity publishes, and its target (20 us amortised)
is checked by measurement, not by a timed test. The run is the one docs/dead-reckoning.md describes: a `Sim` of
`--entities` entities on the bundled map (no viewers, no transit, 1 Hz fixes and ticks, seed 5, the fleet core),
`--warmup` simulated seconds, then `--seconds` more with `Player._publish` wrapped in a `time.thread_time_ns`
timer (this thread's CPU time: other processes on a shared machine do not count, but cache and frequency effects
do, so compare trees by alternated runs). The garbage collections inside the publishes and the fleet's steps are
timed too (`gc.callbacks`) and given apart, and the window starts right after a full collection (`gc.collect()`):
a full collection costs ~0.2 s and comes every ~45-60 simulated s, so without that whether one fell in a 30 s
window was chance (the phase differs between trees that allocate differently). It also prints a digest of every
message the fleet returned and every publish's bytes, so two trees (or the pure and the compiled path) can be shown
to publish the same messages.

`python -m sims.bench.publish_cost [--entities 2000] [--warmup 20] [--seconds 30] [--out FILE.json]`
(also runs as a script path, e.g. under another checkout's interpreter).
"""

from __future__ import annotations

import argparse
import gc
import hashlib
import json
import time


def warmed_sim(entities: int, warmup: int, seconds: int, seed: int):
    """The measured run's simulation, started and stepped `warmup` simulated seconds: the one setup every publish
    measurement shares (`publish_together` too), so their figures are of the same run. `seconds` is only checked."""
    from entitynet.topology_cache import bundled_topology
    from sims.engine.sim import Sim, SimConfig

    if not (0 < entities <= 100_000 and 0 <= warmup <= 3600 and 0 < seconds <= 3600):
        raise ValueError("entities in (0, 100000], warmup in [0, 3600], seconds in (0, 3600]")
    topo, _path = bundled_topology()
    sim = Sim(topo, SimConfig(entities=entities, viewers=0, transit=False, tick_hz=1.0, seed=seed, core="fleet"))
    sim.start()
    for _ in range(warmup):
        sim.step()
    return sim


def measure(entities: int = 2000, warmup: int = 20, seconds: int = 30, seed: int = 5) -> dict:
    """Run the simulation and return the publish count, the mean CPU us per publish, the fleet's CPU us per
    entity-step and the digest of the messages (during the measured seconds)."""
    from entitynet.client.player import Player

    sim = warmed_sim(entities, warmup, seconds, seed)
    inner = Player._publish
    spent = [0, 0, 0]  # ns, publishes, ns of garbage collections inside them
    clock = time.thread_time_ns
    collected = [0, 0, [0, 0, 0]]  # ns so far, start of the current one, collections per generation

    def on_gc(phase: str, info: dict) -> None:
        if phase == "start":
            collected[1] = clock()
            collected[2][info["generation"]] += 1
        else:
            collected[0] += clock() - collected[1]

    def timed(self, *args, **kwargs):
        g0 = collected[0]
        t0 = clock()
        out = inner(self, *args, **kwargs)
        spent[0] += clock() - t0
        spent[1] += 1
        spent[2] += collected[0] - g0
        return out

    gc.collect()  # (the window starts right after a full collection in every tree: the same phase of the collector)
    h = hashlib.sha256()
    fleet_ns = fleet_gc = 0
    Player._publish = timed  # type: ignore[method-assign]
    gc.callbacks.append(on_gc)
    try:
        for _ in range(seconds):
            src = sim.source.step(sim.dt)
            for a in src:
                sim.fleet.add(a)
            g0 = collected[0]
            t0 = clock()
            conns = sim.fleet.step(sim.now)
            fleet_ns += clock() - t0
            fleet_gc += collected[0] - g0
            for msgs in conns:
                for m in msgs:
                    h.update(repr(m).encode())
    finally:
        Player._publish = inner  # type: ignore[method-assign]
        gc.callbacks.remove(on_gc)
    n = spent[1]
    steps = entities * seconds
    return {"entities": entities, "warmup_s": warmup, "seconds": seconds, "seed": seed, "publishes": n,
            "publish_us": spent[0] / n / 1000.0 if n else float("nan"),
            "fleet_us_per_entity_step": fleet_ns / steps / 1000.0,
            "publish_share_of_fleet": spent[0] / fleet_ns if fleet_ns else float("nan"),
            # the same without the garbage collections that fell inside (a full one costs ~0.2 s here and comes
            # every ~30-40 simulated s, so whether one falls in a 30 s window is chance: compare code by these)
            "publish_us_without_gc": (spent[0] - spent[2]) / n / 1000.0 if n else float("nan"),
            "fleet_us_per_entity_step_without_gc": (fleet_ns - fleet_gc) / steps / 1000.0,
            "gc_ms_in_fleet": fleet_gc / 1e6, "gc_collections": collected[2],
            "digest": h.hexdigest()[:16]}


def command(measure_fn, description: str, argv: list[str] | None, seconds: int, seed: int) -> None:
    """A measurement's command line (`--entities --warmup --seconds --seed --out`): `measure_fn`'s result printed as
    JSON and written to `--out` (shared with `sims.bench.publish_ab`)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--entities", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=20)
    ap.add_argument("--seconds", type=int, default=seconds)
    ap.add_argument("--seed", type=int, default=seed)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    text = json.dumps(measure_fn(args.entities, args.warmup, args.seconds, args.seed), indent=1)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")


def main(argv: list[str] | None = None) -> None:
    """The command: one measurement, printed as JSON (and written to `--out`)."""
    command(measure, __doc__.splitlines()[0], argv, 30, 5)


if __name__ == "__main__":
    main()
