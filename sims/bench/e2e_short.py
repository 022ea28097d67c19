"""`python -m sims.bench.e2e_short`: a shorter `bench e2e` for one figure, the brokers' CPU per viewer-second.

The full suite runs seven systems three times for 60 simulated seconds (20+ minutes); iterating on the server's
cost needs only ours against mosquitto, alternated, in the same sitting. This runs the chosen systems of the
suite (`sims.bench.e2e_bench.SYSTEMS`) with the suite's workload but `--seconds` simulated seconds, `--reps`
times alternated, each with a fresh broker, optionally idle (the suite's idle variant: same viewers, cameras
and barrier, no entities), and prints each run's figures and the medians as JSON. The per-viewer-second
figures are comparable with the full run's (the ticks, speed and viewers are the suite's); the totals are not.
To compare with another checkout, run it with `PYTHONPATH` naming that tree: the servers it starts inherit it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

from sims.bench.e2e_bench import DEFAULT_CPUS, SYSTEMS, run_one
from sims.bench.e2e_run import RunParams

FIGURES = ("server_cpu_ms_per_viewer_s", "server_cpu_per_loadgen_cpu", "messages_per_viewer_s", "bytes_per_viewer_s",
           "error_p95_m", "loadgen_cpu_share")


def parse(argv: list[str] | None) -> argparse.Namespace:
    """The arguments; bad ones exit with argparse's usage error before anything starts."""
    ap = argparse.ArgumentParser(prog="python -m sims.bench.e2e_short", description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", default="entitynet,mqtt-disc", help="comma-separated names of bench e2e's systems")
    ap.add_argument("--seconds", type=float, default=40.0, help="simulated seconds per run (the suite: 60)")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--idle", action="store_true", help="no entities: the barrier and subscriptions alone")
    ap.add_argument("--cpus", default=DEFAULT_CPUS,
                    help="as `entitynet bench --cpus` (default: the full suite's, one CPU)")
    a = ap.parse_args(argv)
    known = {s.name for s in SYSTEMS}
    a.names = [n for n in a.systems.split(",") if n]
    unknown = sorted(set(a.names) - known)
    if unknown or not a.names:
        ap.error(f"unknown systems {unknown}; known: {', '.join(sorted(known))}")
    if not 10.0 <= a.seconds <= 600.0 or not 1 <= a.reps <= 10:
        ap.error("--seconds must be 10-600 and --reps 1-10")
    return a


def main(argv: list[str] | None = None) -> int:
    """Run the plan one broker at a time; print every run's figures and the medians."""
    a = parse(argv)
    from sims.bench.affinity import CpuSpecError, pin

    try:
        placement = pin(a.cpus, DEFAULT_CPUS)
    except CpuSpecError as exc:
        print(f"e2e_short: {exc}", file=sys.stderr)
        return 2
    from entitynet.topology_cache import bundled_topology, cache_dir
    from sims.bench.hfp_geohash import cell_boxes
    from sims.bench.switch_systems import find_exe
    from sims.engine.schedule import BUNDLED_FEED, load_schedule

    def progress(msg: str) -> None:
        print(f"[e2e-short] {msg}", file=sys.stderr, flush=True)

    exes = {}
    for name in ("mosquitto", "redis-server"):
        exes[name], how = find_exe(name, name, progress)
        if exes[name] is None and any(s.startswith("mqtt" if name == "mosquitto" else "redis") for s in a.names):
            print(f"e2e_short: {how}", file=sys.stderr)
            return 2
    topo, artifact = bundled_topology(progress, with_pvs=True)
    schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir())
    boxes = cell_boxes(topo)
    p = RunParams(entities=400, viewers=30, seconds=a.seconds, speed=1.5)  # the full suite's, but the seconds
    if a.idle:
        p = replace(p, entities=0, transit=False)
    by_name = {s.name: s for s in SYSTEMS}
    runs: dict[str, list[dict]] = {n: [] for n in a.names}
    with tempfile.TemporaryDirectory(prefix="entitynet-e2e-short-") as tmp:
        for r in range(a.reps):
            for name in a.names[r % len(a.names):] + a.names[:r % len(a.names)]:
                rep = run_one(by_name[name], topo, artifact, schedule, p, exes, boxes, Path(tmp), progress)
                row = {k: rep.get(k) for k in FIGURES}
                runs[name].append(row)
                progress(f"{name} run {r + 1}: {row}")
    medians = {n: {k: statistics.median(row[k] for row in rows) for k in FIGURES if rows[0][k] is not None}
               for n, rows in runs.items()}
    print(json.dumps({"params": {"seconds": a.seconds, "reps": a.reps, "idle": a.idle, "viewers": p.viewers,
                                 "entities": p.entities, "speed": p.speed, "placement": placement},
                      "runs": runs, "medians": medians},
                     indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
