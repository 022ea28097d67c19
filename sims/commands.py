"""`entitynet demo` and `entitynet bench`: the subcommands of `sims`, registered through the entry-point
group `entitynet.commands` (pyproject.toml) so that `entitynet` never imports `sims` (the arrows run
topology <- entitynet <- sims)."""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path

from entitynet.cli import CommandError
from entitynet.commands.options import SEED, bounded_int, port, positive_seconds, time_of_day


# ---- entitynet demo ----------------------------------------------------------------------------------------
def register_demo(sub) -> None:
    """`entitynet demo`: a preset of `entitynet sim` on the bundled Helsinki map and schedule, in real time, with
    the 3D browser viewer (sims/demo.py)."""

    p = sub.add_parser("demo", help="run a live city on loopback (a preset of `sim`): server, trams and buses on "
                                    "the bundled schedule, pedestrians and cars, PVS viewers, the 3D viewer")
    p.add_argument("--entities", type=bounded_int(1, 100_000),
                   default=300, help="pedestrians and cars (default 300; trams and buses "
                                                             "come from the schedule on top)")
    p.add_argument("--viewers", type=bounded_int(0, 100_000),
                   default=24, help="viewers subscribing by PVS (default 24)")
    p.add_argument("--connections", type=bounded_int(1, 1024),
                   default=4, help="connections carrying the entities (default 4)")
    p.add_argument("--duration", type=positive_seconds(),
                   help="stop after this many seconds (default: run until Ctrl-C)")
    p.add_argument("--summary-every", type=positive_seconds(86400),
                   default=5.0, metavar="S", help="summary interval (default 5 s)")
    p.add_argument("--seed", type=SEED, default=1, help="random seed")
    p.add_argument("--port", type=port(), default=0, help="server TCP port (default: any free port)")
    p.add_argument("--no-pvs", action="store_true", help="use an artifact without PVS (subscribe by distance)")
    p.add_argument("--http-port", type=port(special={-1: "no viewer"}), default=8400, metavar="PORT",
                   help="serve the 3D browser viewer here (default 8400; 0 = any free port; -1 = no viewer)")
    p.add_argument("--gtfs", metavar="FEED", help="GTFS zip for the trams and buses (default: the bundled HSL "
                                                  "extract); 'none' for no transit")
    p.add_argument("--start", type=time_of_day, default=8 * 3600.0, metavar="HH:MM",
                   help="service-day time the demo starts at (default 08:00)")
    p.add_argument("--transit", metavar="GTFS", help="instead of the simulated schedule, trams and buses from this "
                   "GTFS feed through the SIRI replay producer and the transit proxy (needs the proxies package)")
    p.add_argument("--report", metavar="FILE.json", help="write the final JSON report here (default: stdout)")
    p.add_argument("--shards", type=bounded_int(1, 64),
                   metavar="K", help="run on a local cluster of K switchboard processes and "
                   "nats-server (`entitynet sim --shards K` with the demo's numbers; no 3D viewer)")
    p.add_argument("--nats-nodes", type=bounded_int(1, 16),
                   default=1, metavar="N", help="nats-server nodes with --shards (default 1)")
    p.set_defaults(func=run_demo_command)


def run_demo_command(args: argparse.Namespace) -> int:
    """Check the numbers (a clear error, not a traceback from deep inside), load the map and the schedule, run
    the preset until done and write its report."""
    import trio

    from entitynet.topology_cache import bundled_topology
    from sims.demo import DemoConfig, run_demo
    from sims.sim_cmd import emit_report, load_feed

    for name in ("entities", "viewers", "connections"):
        if getattr(args, name) < (0 if name == "viewers" else 1):
            raise CommandError(f"--{name} must be at least {0 if name == 'viewers' else 1}")
    if args.transit is not None and not Path(args.transit).is_file():
        raise CommandError(f"GTFS feed {args.transit} not found (no such file)")
    if args.gtfs not in (None, "none") and not Path(args.gtfs).is_file():
        raise CommandError(f"{args.gtfs}: cannot read the feed (no such file)")
    if args.duration is not None and not args.duration > 0:
        raise CommandError("--duration must be a positive number of seconds")
    if not args.summary_every > 0:
        raise CommandError("--summary-every must be positive")
    if args.shards is not None:  # the demo as a preset of `entitynet sim`, on a local cluster (sims.cluster_run)
        if args.transit is not None:
            raise CommandError("--transit does not combine with --shards (the transit proxy publishes to one server)")
        from sims import sim_cmd

        return sim_cmd.run(sim_cmd.sim_args(
            entities=args.entities, viewers=args.viewers, gtfs=args.gtfs, start=args.start, duration=args.duration,
            connections=args.connections, radius=args.no_pvs, seed=args.seed, summary_every=args.summary_every,
            report=args.report, shards=args.shards, nats_nodes=args.nats_nodes))
    start = time.perf_counter()

    def say(msg: str) -> None:
        print(f"[{time.perf_counter() - start:6.1f}s] {msg}", file=sys.stderr, flush=True)

    topo, path = bundled_topology(say, with_pvs=not args.no_pvs)
    c = topo.meta["counts"]
    say(f"Helsinki topology {path.name}: {c['edges']} edges, {topo.n_cells} cells, "
        f"{'PVS for ' + str(topo.meta['pvs']['view_cells']) + ' view cells' if 'pvs' in topo.meta else 'no PVS'}")
    schedule = None
    if args.gtfs != "none" and args.transit is None:
        schedule = load_feed(args.gtfs, topo, None, args.seed, args.start, say)
    config = DemoConfig(
        entities=args.entities, viewers=args.viewers, connections=args.connections, duration=args.duration,
        summary_every=args.summary_every, seed=args.seed, port=args.port, transit=args.transit,
        http_port=None if args.http_port < 0 else args.http_port, start=args.start,
    )  # fmt: skip
    try:
        report = trio.run(run_demo, topo, path, config, say, schedule)
    except* OSError as group:
        first = group.exceptions[0]
        while isinstance(first, BaseExceptionGroup):
            first = first.exceptions[0]
        raise CommandError(f"cannot listen: {first} (choose another --http-port, or 0 for any free port)") from None
    emit_report(report, args.report, say)
    return 0


# ---- entitynet bench ---------------------------------------------------------------------------------------
def register_bench(sub) -> None:
    """`entitynet bench SUITE [--quick] --out FILE.json`: the suites of `sims.bench.all_suites()`."""
    from sims.bench import all_suites

    p = sub.add_parser("bench", help="run a benchmark suite and write its JSON report")
    p.add_argument("suite", choices=sorted(all_suites()), help="which suite")
    p.add_argument("--quick", action="store_true", help="a smaller run that finishes in under a minute")
    p.add_argument("--out", metavar="FILE.json", help="write the JSON report here (default: print it)")
    p.add_argument("--topology", metavar="FILE", help="topology artifact (default: the bundled Helsinki map)")
    p.add_argument("--cpus", metavar="LIST", help="where the suite, its load and the servers it starts run: 'all', "
                   "'one' (the lowest allowed CPU) or CPU numbers like 0,1 or 0-3 (default: 'one' for e2e, whose "
                   "brokers' CPU repeats only so on a small VM; 'all' for the others)")
    p.set_defaults(func=run_bench_command)


def progress(msg: str) -> None:
    """Bench progress goes to stderr so that stdout stays the results (pipe it into jq)."""
    print(f"[bench] {msg}", file=sys.stderr, flush=True)


def run_bench_command(args: argparse.Namespace) -> int:
    """Import the suite's module only now (a suite's heavy imports cost nothing to the other commands)."""
    from sims.bench import all_suites
    from sims.bench.affinity import CpuSpecError, pinned
    from sims.bench.report import write_report
    from topology.artifact import ArtifactError

    module = importlib.import_module(all_suites()[args.suite])
    try:  # here once, not per suite: a bad --topology or an unwritable --out is one line in every suite
        with pinned(args.cpus, getattr(module, "DEFAULT_CPUS", "all")) as placement:
            if placement["pinned"]:
                progress(f"running on CPU {','.join(map(str, placement['cpus']))} (--cpus {placement['cpus_asked']})")
            body = module.run(args, progress)
        body.setdefault("params", {})["placement"] = placement
        report = write_report(args.suite, body, args.out)
    except (ArtifactError, OSError, CpuSpecError) as exc:
        raise CommandError(str(exc)) from None
    print(json.dumps(report["results"], indent=2, default=float))
    if args.out:
        progress(f"report written to {args.out}")
    return 0
