"""Micro-measures of the fleet core's fix path (docs/simulation.md, "The fleet core"): where a fix's CPU time goes,
and the compiled kernels against their numpy references on the same inputs.

    python -m sims.bench.fleet_micro split [--entities 1000] [--seconds 20] [--warmup 20]
    python -m sims.bench.fleet_micro kernels [--entities 1000]

`split`: the simulator's fleet (`sims.engine.clients.Fleet`, the fleet core) stepped alone on the bundled map,
1 Hz fixes, CPU time (`time.process_time`) of the whole step per fix and of its parts: the vectorised fix
(`fleet_fix.fast_fixes`), the publishes (`Player._publish`), the fixes left to the Players (`Player.feed`, their
publishes included) and the read-back after a Player's call (`FleetCore._refresh`). `kernels`: records the
kernels' calls of five ticks after 25, then times each compiled kernel (`entitynet/client/_fleet.pyx`) and its
numpy reference on the recorded inputs, alternated five times, medians. Both print; figures on a shared machine
are only worth comparing within one sitting (alternate the trees or paths compared).
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import Any

from entitynet.client import fleet_kernels, fleet_near
from entitynet.client.fleet import FleetCore
from entitynet.client.player import Player


def _fleet(n: int):
    """A seeded simulation of n entities (no viewers, no transit) and its client fleet through the fleet core."""
    from entitynet.topology_cache import bundled_topology
    from sims.bench.fleet_memory import sim_fleet

    topo, _ = bundled_topology(lambda *a: None, with_pvs=True)
    return sim_fleet(topo, n, seed=5)


def _drive(sim, fleet, ticks: int, on_tick: Callable[[int], None]) -> tuple[int, float]:
    """Step the world and the fleet `ticks` times (1 s); `on_tick(k)` before each step. Returns the fixes and
    the step's CPU seconds of the ticks after the first."""
    fixes, spent = 0, 0.0
    for k in range(ticks):
        if k:
            sim.world.step(1.0)
            for a in sim.population.step():
                fleet.add(a)
        on_tick(k)  # (the fleet's step takes the world's removals itself)
        before = fleet.counters["fixes"]
        t = time.process_time()
        fleet.step(sim.now)
        if k:
            spent += time.process_time() - t
            fixes += fleet.counters["fixes"] - before
    return fixes, spent


def split(n: int, seconds: int, warmup: int) -> dict[str, float]:
    """CPU microseconds per fix of the fleet's step and of its parts (see the module docstring)."""
    import entitynet.client.fleet as fleet_mod

    spent: dict[str, float] = {}
    on = [False]
    undo = []

    def wrap(owner: Any, name: str, key: str) -> None:
        f = getattr(owner, name)
        undo.append((owner, name, f))

        def timed(*a, **kw):
            t = time.process_time()
            try:
                return f(*a, **kw)
            finally:
                if on[0]:
                    spent[key] = spent.get(key, 0.0) + time.process_time() - t
        setattr(owner, name, timed)

    wrap(fleet_mod, "fast_fixes", "array_path")
    wrap(Player, "_publish", "publish")
    wrap(Player, "feed", "scalar_feed")
    wrap(FleetCore, "_refresh", "refresh")
    try:
        sim, fleet = _fleet(n)
        _drive(sim, fleet, warmup + 1, lambda k: None)
        on[0] = True
        fixes, step = _drive(sim, fleet, seconds + 1, lambda k: None)
    finally:
        for owner, name, f in undo:
            setattr(owner, name, f)
    c = fleet.fleet_core.counters
    out = {"fixes": fixes, "fixes_per_s": fixes / step, "step_us": 1e6 * step / fixes}
    out.update({f"{k}_us": 1e6 * v / fixes for k, v in sorted(spent.items())})
    out["share_in_arrays"] = c["vector_fixes"] / max(c["vector_fixes"] + c["scalar_fixes"], 1)
    return out


def kernels(n: int) -> dict[str, dict[str, float]]:
    """Per compiled kernel: its CPU microseconds per fix and its numpy reference's on the same recorded inputs."""
    k = fleet_kernels.COMPILED
    if k is None:
        raise SystemExit("the compiled fleet kernels were not built")
    from entitynet.client.tracker import ALONG_SCALE

    calls: dict[str, list[tuple]] = {name: [] for name in ("project", "path_xy", "near", "s_of", "best_on")}
    on = [False]
    geo_cls, tables_cls = fleet_kernels.Geometry, fleet_near.NearTables
    undo = [(geo_cls, "project"), (geo_cls, "path_xy"), (tables_cls, "near"), (fleet_near, "s_of_rows"),
            (fleet_near, "best_on_rows")]
    saved = [getattr(o, a) for o, a in undo]

    def recorder(name: str, f: Callable) -> Callable:
        def rec(*a):
            if on[0]:
                calls[name].append(tuple(v.copy() if hasattr(v, "copy") else v for v in a))
            return f(*a)
        return rec

    for (owner, attr), name, f in zip(undo, calls, saved, strict=True):
        setattr(owner, attr, recorder(name, f))
    import entitynet.client.fleet_fix as fleet_fix

    fix_s_of = fleet_fix.s_of_rows
    fleet_fix.s_of_rows = fleet_near.s_of_rows
    try:
        sim, fleet = _fleet(n)
        _drive(sim, fleet, 26, lambda k: None)
        on[0] = True
        fixes, _ = _drive(sim, fleet, 6, lambda k: None)
    finally:
        for (owner, attr), f in zip(undo, saved, strict=True):
            setattr(owner, attr, f)
        fleet_fix.s_of_rows = fix_s_of
    wt = 1.0 / (ALONG_SCALE * ALONG_SCALE)
    pairs = {"project": (lambda a: k.project(*a), lambda a: a[0].project_np(*a[1:])),
             "path_xy": (lambda a: k.path_xy(*a), lambda a: a[0].path_xy_np(*a[1:])),
             "near": (lambda a: k.near(*a), lambda a: a[0].near_np(*a[1:])),
             "s_of": (lambda a: k.s_of_rows(*a), lambda a: fleet_near.s_of_rows_np(*a)),
             "best_on": (lambda a: k.best_on_rows(*a, wt), lambda a: fleet_near.best_on_rows_np(*a))}
    out = {}
    for name, recorded in calls.items():
        times: dict[int, list[float]] = {0: [], 1: []}
        for rep in range(5):
            for which in ((0, 1) if rep % 2 else (1, 0)):
                t = time.process_time()
                for a in recorded:
                    pairs[name][which](a)
                times[which].append(time.process_time() - t)
        c, p = statistics.median(times[0]), statistics.median(times[1])
        out[name] = {"calls": len(recorded), "compiled_us_per_fix": 1e6 * c / fixes,
                     "numpy_us_per_fix": 1e6 * p / fixes, "ratio": p / c if c > 0 else float("nan")}
    return out


def main(argv: list[str] | None = None) -> None:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(prog="python -m sims.bench.fleet_micro", description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("split", "kernels"))
    ap.add_argument("--entities", type=int, default=1000)
    ap.add_argument("--seconds", type=int, default=20)
    ap.add_argument("--warmup", type=int, default=20)
    args = ap.parse_args(argv)
    if args.what == "split":
        r = split(args.entities, args.seconds, args.warmup)
        print(" ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()))
    else:
        for name, r in kernels(args.entities).items():
            print(f"{name:8s} calls {r['calls']:3d}  compiled {r['compiled_us_per_fix']:6.3f}  numpy "
                  f"{r['numpy_us_per_fix']:6.3f} us/fix  x{r['ratio']:.1f}")


if __name__ == "__main__":
    main()
