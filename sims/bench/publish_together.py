"""Whether a tick's publishes computed together find the memory they read in cache (issue 22, item 2).

Why a command: a publish's cover (`Coverage.occupation`) costs about twice as much cold as made again at once
(`sims.bench.publish_ab`), and the plan for the 20 us target was to compute a tick's publishes together, so that
each map table is read once while cached. That only pays if what the cold call waits for is shared between the
entities of a tick (the map's tables, the code), not each entity's own objects. This measures it on the run of
`publish_cost` (a `Sim` of `--entities` entities on the bundled map, the fleet core, 1 Hz, `--warmup` simulated
seconds, then `--seconds` more): after each tick's fleet step, the covers of the entities that published a network
model in it are made again (the cover only reads the Player; its memos are functions of the map) in four ways, each
timed as a whole pass (`time.thread_time_ns`, us per cover):

- `together`: one after the other in the fleet's order (a batched publish's best case for shared tables: every
  publisher's cover in a row, nothing else in between);
- `together_again`: the same pass once more (whatever ~300 covers leave in cache);
- `by_edge`: the same, sorted by the ghost's first edge (neighbours on the map one after the other);
- `first` / `again`: each entity's cover twice in a row, the first and the second call summed apart.

Each pass's covers are checked equal to the first pass's (cells, validity, periods). If `together` is near `first`
and far above `again`, the cold cost is the entity's own and no order of a tick's publishes removes it.

`python -m sims.bench.publish_together [--entities 2000] [--warmup 20] [--seconds 10] [--seed 5] [--out FILE.json]`
"""

from __future__ import annotations

import statistics
import time


def measure(entities: int = 2000, warmup: int = 20, seconds: int = 10, seed: int = 5) -> dict:
    """Per tick the four passes' CPU us per cover; their medians over the ticks and the covers counted."""
    from entitynet.client.modes import EDGE
    from entitynet.client.motion import NetworkModel
    from sims.bench.publish_cost import warmed_sim

    sim = warmed_sim(entities, warmup, seconds, seed)
    core = sim.fleet.fleet_core
    clock = time.thread_time_ns
    passes: dict[str, list[float]] = {k: [] for k in ("together", "together_again", "by_edge", "first", "again")}
    covers = 0

    def one(p, now: float):
        return p.coverage.occupation(now, p.ghost, p.tracker, p.estimate_xy, p.coverage.hold.lateral_at(now))

    def run(players: list, now: float) -> tuple[float, list]:
        t0 = clock()
        out = [one(p, now) for p in players]
        return (clock() - t0) / 1000.0 / len(players), out

    for _ in range(seconds):
        for a in sim.source.step(sim.dt):
            sim.fleet.add(a)
        before = [None if p is None else p.ghost for p in core.players]
        sim.fleet.step(sim.now)
        now = sim.now
        slots = [s for s, p in enumerate(core.players)
                 if p is not None and s < len(before) and isinstance(p.ghost, NetworkModel)
                 and p.ghost is not before[s] and p.tracker is not None and p.tracker.place is EDGE]
        pubs = [core.players[s] for s in sorted(slots, key=lambda s: int(core.order[s]))]  # the fleet's order
        if not pubs:
            continue
        covers += len(pubs)
        us, ref = run(pubs, now)
        passes["together"].append(us)
        us, out = run(pubs, now)
        passes["together_again"].append(us)
        if out != ref:
            raise AssertionError("a cover made again differs from the first")
        by_edge = sorted(range(len(pubs)), key=lambda i: pubs[i].ghost.path.edges[0][0])
        us, out = run([pubs[i] for i in by_edge], now)
        passes["by_edge"].append(us)
        if out != [ref[i] for i in by_edge]:
            raise AssertionError("a cover made in another order differs")
        first = again = 0
        for p, r in zip(pubs, ref, strict=True):
            t0 = clock()
            a1 = one(p, now)
            t1 = clock()
            a2 = one(p, now)
            t2 = clock()
            first += t1 - t0
            again += t2 - t1
            if a1 != r or a2 != r:
                raise AssertionError("a cover made twice differs")
        passes["first"].append(first / 1000.0 / len(pubs))
        passes["again"].append(again / 1000.0 / len(pubs))
    med = {k: statistics.median(v) if v else float("nan") for k, v in passes.items()}
    return {"entities": entities, "warmup_s": warmup, "seconds": seconds, "seed": seed, "covers": covers,
            "median_us_per_cover": med, "per_tick_us": passes}


def main(argv: list[str] | None = None) -> None:
    """The command: one measurement, printed as JSON (and written to `--out`)."""
    from sims.bench.publish_cost import command

    command(measure, __doc__.splitlines()[0], argv, 10, 5)


if __name__ == "__main__":
    main()
