"""Memory of the honest-client fleet per tracked entity, and whether it grows over a long run (issue 22).

    python -m sims.bench.fleet_memory [--entities 1000] [--seconds 3600] [--samples 12] [--traced-seconds 120]

Why: the fleet core keeps every entity's client state in one `Record` (entitynet/client/state.py) plus each
entity's `Player` and its parts, its path and ghost; per map the placer keeps caches (segment tables, the near
tables, the way-back paths) that fill as the entities reach new parts of the map and are bounded by it. A
city-scale run holds thousands of entities for hours, so what a tracked entity costs, and that nothing of it
accumulates (a leaked Player, a ring or a dict per entity that only grows), is a figure to state, not to guess.

Two runs of the simulator's fleet (`sims.engine.clients.Fleet`, the fleet core, 1 Hz fixes, the population
coming and going as in `entitynet sim`, no viewers, no server), each stepped alone:

1. **Bytes per entity** (`traced`, first): `traced_seconds` simulated seconds under `tracemalloc` (one frame
   per allocation; it slows the run about 8x, hence the short run). The live allocations made by the client code
   (entitynet/client/, and sims/engine/clients.py's per-entity bookkeeping) are summed by file: the allocation
   site names the owner, a Python object or a numpy block allocated there belongs to the client core whoever
   holds it. The per-map caches (the files in `SHARED_FILES`) are given apart (`shared_bytes`: what this
   run built of them; they go on filling as the entities reach new edges, `seg_tables` below); the rest divided
   by the entities tracked is `bytes_per_entity` (an upper bound: path.py's share holds the way-back cache's
   paths too). `row_bytes`: the record's own array state per row (`Record.nbytes_per_row`), a floor that the
   Python objects come on top of.
2. **Growth** (`growth`): `seconds` simulated seconds (default an hour) untraced, sampled `samples` times after
   a full collection: the fleet's fixes per CPU second of its step since the previous sample (the caches cold
   in the first interval, warm in the last; `fleet_fixes_per_s_median` over the intervals), the process's RSS,
   the entities tracked, the client objects alive (instances of classes defined in entitynet.client, in the
   whole process, the per-map cache objects counted apart, `seg_tables` the placers' segment tables among
   them) and this run's `Player` objects alive (held weakly). A Player alive beyond those tracked is a leak
   (`players_leaked`); client objects per tracked entity at the end against half-way
   (`objects_per_entity_growth`) is the per-entity growth; the RSS's growth over the second half is given as
   it is, caches and the world's own allocations included (its absolute figures include what the traced run
   left in the allocator's arenas).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import statistics
import sys
import time
import tracemalloc
import weakref
from typing import Any

# files whose allocations are per-map caches, shared by all the entities on one map (bounded by the map)
SHARED_FILES = ("placement.py", "fleet_near.py", "fleet_kernels.py", "coverage.py", "lateral.py", "network.py")
# classes of entitynet.client whose instances are per-map caches (bounded by the map), not per-entity state
# (`Path` with them: the way-back cache holds up to 16,384 paths; an entity's own paths are a few of them)
SHARED_CLASSES = ("_SegTable", "Path", "Placer", "NearIndex", "NetView", "EntityType")
CLIENT_DIR = os.sep.join(("entitynet", "client")) + os.sep
CLIENT_FILE = os.sep.join(("sims", "engine", "clients.py"))


def _owner(filename: str) -> str | None:
    """The client file that made an allocation (its base name), or None when the client code did not."""
    if CLIENT_DIR in filename or filename.endswith(CLIENT_FILE):
        return os.path.basename(filename)
    return None


def client_bytes(snapshot: tracemalloc.Snapshot) -> dict[str, int]:
    """Live bytes per client file in `snapshot` (the files of `_owner`)."""
    out: dict[str, int] = {}
    for stat in snapshot.statistics("filename"):
        name = _owner(stat.traceback[0].filename)
        if name is not None:
            out[name] = out.get(name, 0) + stat.size
    return out


def sim_fleet(topo, entities: int, seed: int):
    """A seeded simulation of `entities` on `topo` (no viewers, no transit, 1 s ticks) and its client fleet
    through the fleet core at 1 Hz fixes, the population started: what this module and `fleet_micro` step."""
    from sims.engine.clients import Fleet
    from sims.engine.sim import Sim, SimConfig

    sim = Sim(topo, SimConfig(entities=entities, viewers=0, transit=False, tick_hz=1.0, seed=seed, core="fleet"))
    fleet = Fleet(sim.world, sim.config.connections, fix_interval=1.0, gps_sigma=sim.config.gps_sigma,
                  seed=sim.config.seed, core="fleet")
    for a in sim.population.start():
        fleet.add(a)
    return sim, fleet


def _tick(sim, fleet, born: weakref.WeakSet | None = None) -> float:
    """One simulated second: the world, its arrivals, the fleet (which takes the world's removals itself);
    `born` is given every Player made (held weakly: alive only while something else holds it). Returns the CPU
    seconds of the fleet's step."""
    sim.world.step(1.0)
    for a in sim.population.step():
        fleet.add(a)
        if born is not None:
            born.add(fleet.players[a.id])
    t = time.process_time()
    fleet.step(sim.now)
    return time.process_time() - t


def traced(topo, entities: int, seconds: float, seed: int = 5, progress=lambda msg: None) -> dict[str, Any]:
    """Part 1 (the module docstring): bytes per tracked entity from the client code's live allocations."""
    was = tracemalloc.is_tracing()
    if not was:
        tracemalloc.start(1)
    try:
        sim, fleet = sim_fleet(topo, entities, seed)
        fleet.step(sim.now)
        for _ in range(int(seconds)):
            _tick(sim, fleet)
        gc.collect()
        by_file = client_bytes(tracemalloc.take_snapshot())
    finally:
        if not was:
            tracemalloc.stop()
    tracked = len(fleet.players)
    total = sum(by_file.values())
    shared = sum(v for f, v in by_file.items() if f in SHARED_FILES)
    progress(f"fleet memory: {tracked} tracked after {int(seconds)} s: {(total - shared) / max(tracked, 1):,.0f} B "
             f"per entity, per-map caches {shared / 1e6:.1f} MB")
    return {"seconds": int(seconds), "tracked": tracked, "row_bytes": fleet.fleet_core.rec.nbytes_per_row(),
            "bytes_per_entity": round((total - shared) / max(tracked, 1), 1), "shared_bytes": shared,
            "by_file": dict(sorted(by_file.items(), key=lambda kv: -kv[1]))}


def _census() -> tuple[int, int, int]:
    """(client objects alive but the per-map caches, per-map cache objects alive, of which the placers'
    segment tables), in the whole process."""
    per, shared, tables = 0, 0, 0
    for o in gc.get_objects():
        t = type(o)
        mod = t.__dict__.get("__module__")  # (a str on classes defined in Python; absent or not a str on some)
        if isinstance(mod, str) and mod.startswith("entitynet.client"):
            if t.__name__ in SHARED_CLASSES:
                shared += 1
                tables += t.__name__ == "_SegTable"
            else:
                per += 1
    return per, shared, tables


def growth(topo, entities: int, seconds: float, samples: int, seed: int = 5,
           progress=lambda msg: None) -> dict[str, Any]:
    """Part 2 (the module docstring): the fleet over `seconds`, sampled `samples` times."""
    import psutil

    proc = psutil.Process()
    ticks = int(seconds)
    at = sorted({max(1, round(ticks * (k + 1) / samples)) for k in range(samples)})
    sim, fleet = sim_fleet(topo, entities, seed)
    born = weakref.WeakSet(fleet.players.values())  # this run's Players (the process may hold others')
    fleet.step(sim.now)
    rows: list[dict[str, Any]] = []
    t0 = time.monotonic()
    step_cpu, fixes_before = 0.0, fleet.counters["fixes"]
    for k in range(1, ticks + 1):
        step_cpu += _tick(sim, fleet, born)
        if k in at:
            fixes = fleet.counters["fixes"] - fixes_before
            rate = round(fixes / step_cpu, 1) if step_cpu > 0 else 0.0
            step_cpu, fixes_before = 0.0, fleet.counters["fixes"]
            gc.collect()
            per, shared, tables = _census()
            players = len(born)
            tracked = len(fleet.players)
            rows.append({"t_s": k, "tracked": tracked, "rss_bytes": proc.memory_info().rss,
                         "client_objects": per, "players_alive": players, "cache_objects": shared, "seg_tables": tables,
                         "objects_per_entity": round(per / max(tracked, 1), 2), "fleet_rows": fleet.fleet_core.rec.cap,
                         "fleet_fixes_per_s": rate})
            progress(f"fleet memory: t={k} s, {tracked} tracked, {players} Players alive, "
                     f"{per / max(tracked, 1):.1f} client objects each, RSS {rows[-1]['rss_bytes'] / 1e6:.0f} MB "
                     f"({time.monotonic() - t0:.0f} s)")
    half = min(rows, key=lambda r: abs(r["t_s"] - ticks / 2))
    last = rows[-1]
    return {"seconds": ticks, "samples": rows,
            "players_leaked": max(r["players_alive"] - r["tracked"] for r in rows),
            "objects_per_entity_growth": round(last["objects_per_entity"] / max(half["objects_per_entity"], 1e-9)
                                               - 1.0, 4),
            "rss_growth_second_half_bytes": last["rss_bytes"] - half["rss_bytes"],
            # the fleet's fixes per CPU second of its step: the median over the intervals between samples, and
            # the first and the last interval (the per-map caches cold, segment tables built as entities reach
            # new edges, against warm)
            "fleet_fixes_per_s_median": statistics.median(r["fleet_fixes_per_s"] for r in rows),
            "fleet_fixes_per_s_first": rows[0]["fleet_fixes_per_s"],
            "fleet_fixes_per_s_last": last["fleet_fixes_per_s"],
            "cache_objects_growth_second_half": last["cache_objects"] - half["cache_objects"]}


def measure(topo, entities: int = 1000, seconds: float = 3600.0, samples: int = 12, traced_seconds: float = 120.0,
            seed: int = 5, progress=lambda msg: None) -> dict[str, Any]:
    """Both parts on `topo` (see the module docstring); the report."""
    if entities < 1 or seconds < 2 or samples < 2 or traced_seconds < 1:
        raise ValueError("need entities >= 1, seconds >= 2, samples >= 2 and traced seconds >= 1 "
                         f"(got {entities}, {seconds}, {samples}, {traced_seconds})")
    # (traced first: the per-map caches are built under tracing, so `shared_bytes` counts what the run built)
    t = traced(topo, entities, traced_seconds, seed, progress)
    g = growth(topo, entities, seconds, samples, seed, progress)
    return {"entities": entities, "seed": seed, "row_bytes": t["row_bytes"], "bytes_per_entity": t["bytes_per_entity"],
            "players_leaked": g["players_leaked"], "objects_per_entity_growth": g["objects_per_entity_growth"],
            "traced": t, "growth": g}


def main(argv: list[str] | None = None) -> None:
    """`python -m sims.bench.fleet_memory`: both parts on the bundled map, the report printed (and written with
    --out); bad sizes are a usage error, not a traceback."""
    ap = argparse.ArgumentParser(prog="python -m sims.bench.fleet_memory", description=__doc__.split("\n\n")[0])
    ap.add_argument("--entities", type=int, default=1000)
    ap.add_argument("--seconds", type=float, default=3600.0, help="simulated seconds of the growth run")
    ap.add_argument("--samples", type=int, default=12, help="samples of the growth run")
    ap.add_argument("--traced-seconds", type=float, default=120.0, help="simulated seconds under tracemalloc")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", help="also write the report as JSON here")
    args = ap.parse_args(argv)
    from entitynet.topology_cache import bundled_topology

    try:
        if args.entities < 1 or args.seconds < 2 or args.samples < 2 or args.traced_seconds < 1:
            raise ValueError("--entities >= 1, --seconds >= 2, --samples >= 2 and --traced-seconds >= 1, please")
        topo, _ = bundled_topology(lambda *a: None, with_pvs=True)
        rep = measure(topo, args.entities, args.seconds, args.samples, args.traced_seconds, args.seed,
                      progress=lambda m: print(m, file=sys.stderr, flush=True))
    except ValueError as e:
        ap.error(str(e))
    text = json.dumps(rep, indent=1)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
