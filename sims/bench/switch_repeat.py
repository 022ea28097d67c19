"""One step of the switch benchmark, run several times with the systems (and server variants) alternated, and
the medians: `python -m sims.bench.switch_repeat --entities 5000 --reps 4 --systems entitynet,redis`.

Why: on a shared 2-core machine one run's p99 moves by tens of milliseconds from run to run (ours at the
standard load: 59-105 ms in one afternoon, same code), so one ladder step cannot tell two servers, or two
settings of ours, apart. Alternating them run by run puts the machine's drift on all of them alike, and the
median of a few runs is what a comparison may quote. `--variant NAME="ARGS"` runs our server once per
variant with extra `entitynet serve` options (e.g. `--variant python="--gc-full-every 0" --variant default=""`).
"""

from __future__ import annotations

import argparse
import json
import random
import shlex
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from sims.bench import switch_bench as bench
from sims.bench.switch_ladder import OfferedCounter
from sims.bench.switch_systems import find_exe, pin_loadgen, pin_plan, started, usable_cores, workload_params
from sims.mobility import Walkers

FIGURES = ("deliveries_per_s", "offered_deliveries_per_s", "latency_p50_ms", "latency_p99_ms",
           "server_cpu_cores", "machine_busy_cores", "cpu_s_per_million_deliveries", "rss_bytes_per_entity",
           "rss_bytes_per_subscription", "server_messages_out_per_s", "server_frames_out_per_s",
           "server_queue_latency_p50_le_ms", "server_queue_latency_p99_le_ms")


def runs_plan(systems: list[str], variants: dict[str, str], reps: int) -> list[tuple[int, str, str, str]]:
    """(rep, label, system, extra server args) in the order they run: every rep runs every system, ours once
    per variant, so that drift in the machine's load falls on all alike."""
    plan = []
    for rep in range(reps):
        for system in systems:
            if system == "entitynet" and variants:
                plan += [(rep, f"entitynet[{name}]", system, args) for name, args in variants.items()]
            else:
                plan.append((rep, system, system, ""))
    return plan


def medians(rows: list[dict[str, Any]]) -> dict[str, dict[str, float | None]]:
    """Per label, the median of each figure over its runs (None where no run had it)."""
    out: dict[str, dict[str, float | None]] = {}
    for label in dict.fromkeys(r["label"] for r in rows):
        mine = [r for r in rows if r["label"] == label]
        out[label] = {k: (statistics.median(v) if (v := [r[k] for r in mine if r.get(k) is not None]) else None)
                      for k in FIGURES}
        out[label]["runs"] = len(mine)
    return out


def _run_plan(plan_runs, reps: int, p: dict[str, Any], plan: dict[str, Any], exes: dict[str, str | None], topo,
              topo_path: str, cells, progress) -> list[dict[str, Any]]:
    """Each planned run on a fresh server, one after the other; a row of `FIGURES` per run."""
    rows = []
    for rep, label, system, extra in plan_runs:
        progress(f"run {rep + 1}/{reps}: {label}")
        p["server_args"] = shlex.split(extra)
        with tempfile.TemporaryDirectory(prefix="switch-repeat-") as tmpd, \
                started(system, exes[system], topo_path, topo.digest, p, plan, Path(tmpd), progress) as \
                (driver, proc, scrape):
            res = bench._run_load(driver, proc,
                                  lambda: Walkers(topo, p["entities"], random.Random(p["seed"] + 1)),
                                  cells, p, progress, scrape, OfferedCounter(cells, int(topo.n_cells)))
        row = {"rep": rep, "label": label, "system": system, "server_args": extra, "time": time.time(),
               **{k: res.get(k) for k in FIGURES}}
        rows.append(row)
        progress(json.dumps({k: row[k] for k in ("label", "latency_p50_ms", "latency_p99_ms", "deliveries_per_s")}))
    return rows


def _parse_variants(items: list[str]) -> dict[str, str]:
    variants = {}
    for item in items:
        name, sep, args = item.partition("=")
        if not sep or not name:
            raise SystemExit(f"--variant wants NAME=ARGS, not {item!r}")
        variants[name] = args
    return variants


def main(argv: list[str] | None = None) -> int:
    """The command: parse, run the plan one run at a time (a fresh server each), print the medians and write
    the report; bad arguments exit with argparse's usage error before anything starts."""
    ap = argparse.ArgumentParser(prog="python -m sims.bench.switch_repeat", description=__doc__.split("\n\n")[0])
    ap.add_argument("--entities", type=int, default=5000)
    ap.add_argument("--viewers", type=int, default=1000)
    ap.add_argument("--systems", default="entitynet,redis", help="comma-separated: entitynet, redis, nats")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=ARGS",
                    help="run our server once per variant with these extra `serve` options")
    ap.add_argument("--reps", type=int, default=4)
    ap.add_argument("--warmup", type=float, default=5.0)
    ap.add_argument("--window", type=float, default=20.0)
    ap.add_argument("--topology", help="artifact (default: the bundled Helsinki map with PVS)")
    ap.add_argument("--out", help="write the runs and medians here as JSON")
    a = ap.parse_args(argv)
    systems = [s for s in a.systems.split(",") if s]
    unknown = set(systems) - {"entitynet", "redis", "nats"}
    if unknown or a.reps < 1 or a.entities < 1 or a.viewers < 1 or not a.window > 0 or not a.warmup >= 0:
        ap.error(f"bad arguments (unknown systems {sorted(unknown)})" if unknown else "counts and times must be > 0")
    variants = _parse_variants(a.variant)
    from topology.artifact import load

    def progress(msg: str) -> None:
        print(f"[repeat] {msg}", file=sys.stderr, flush=True)

    topo_path = bench._topology_path(argparse.Namespace(topology=a.topology), progress, False)
    topo = load(topo_path)
    cores = usable_cores()
    plan = pin_plan(cores)
    p: dict[str, Any] = {"entities": a.entities, "viewers": a.viewers, **workload_params(cores, plan),
                         "warmup_s": a.warmup, "window_s": a.window}
    cells = bench._view_cells(topo, a.viewers, p, [], progress)
    exes = {"entitynet": sys.executable}
    for system in systems:
        if system != "entitynet":
            exes[system], how = find_exe(f"{system}-server", f"{system}-server", progress)
            if exes[system] is None:
                ap.error(how)
    unpin = pin_loadgen(plan)  # as the ladder does: the readers (forked) inherit it
    try:
        rows = _run_plan(runs_plan(systems, variants, a.reps), a.reps, p, plan, exes, topo, topo_path, cells,
                         progress)
    finally:
        unpin()
    report = {"params": {**p, "reps": a.reps, "systems": systems, "variants": a.variant, "pinned": plan["pinned"],
                         "pin_note": plan["note"]},
              "runs": rows, "medians": medians(rows)}
    text = json.dumps(report, indent=1, default=float)
    if a.out:
        Path(a.out).write_text(text)
    print(json.dumps(report["medians"], indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
