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


# ---- entitynet demo ----------------------------------------------------------------------------------------
def register_demo(sub) -> None:
    """`entitynet demo`: the bundled Helsinki map, a shard server, a few hundred honest clients and viewers."""
    p = sub.add_parser("demo", help="run a live city on loopback: server, honest clients, PVS viewers")
    p.add_argument("--entities", type=int, default=300, help="simulated entities (default 300)")
    p.add_argument("--viewers", type=int, default=24, help="viewers subscribing by PVS (default 24)")
    p.add_argument("--connections", type=int, default=4, help="connections carrying the entities (default 4)")
    p.add_argument("--duration", type=float, help="stop after this many seconds (default: run until Ctrl-C)")
    p.add_argument("--summary-every", type=float, default=5.0, metavar="S", help="summary interval (default 5 s)")
    p.add_argument("--seed", type=int, default=1, help="random seed")
    p.add_argument("--port", type=int, default=0, help="server TCP port (default: any free port)")
    p.add_argument("--no-pvs", action="store_true", help="use an artifact without PVS (subscribe by distance)")
    p.add_argument("--http-port", type=int, default=8400, metavar="PORT",
                   help="serve the 3D browser viewer here (default 8400; 0 = any free port; -1 = no viewer)")
    p.add_argument("--transit", metavar="GTFS", help="add trams and buses from this GTFS feed through the SIRI "
                   "replay producer and the transit proxy (needs the proxies package)")
    p.add_argument("--shards", type=int, metavar="K", help="run on a local cluster of K switchboard processes and "
                   "nats-server (`entitynet sim --shards K` with the demo's numbers; no 3D viewer)")
    p.add_argument("--nats-nodes", type=int, default=1, metavar="N", help="nats-server nodes with --shards (default 1)")
    p.set_defaults(func=run_demo_command)


def run_demo_command(args: argparse.Namespace) -> int:
    """Check the numbers (a clear error, not a traceback from deep inside), then run the demo until done."""
    import trio

    from entitynet.topology_cache import bundled_topology
    from sims.demo import DemoConfig, run_demo

    for name in ("entities", "viewers", "connections"):
        if getattr(args, name) < (0 if name == "viewers" else 1):
            raise CommandError(f"--{name} must be at least {0 if name == 'viewers' else 1}")
    if args.transit is not None and not Path(args.transit).exists():
        raise CommandError(f"GTFS feed {args.transit} not found")
    if args.duration is not None and not args.duration > 0:
        raise CommandError("--duration must be a positive number of seconds")
    if args.shards is not None:  # the demo as a preset of `entitynet sim`, on a local cluster (sims.cluster_run)
        from sims import sim_cmd

        return sim_cmd.run(argparse.Namespace(
            entities=args.entities, car_share=0.3, viewers=args.viewers, gtfs=args.transit, date=None,
            start=8 * 3600.0, duration=args.duration, speed=1.0, tick_hz=2.0, server=None, token="",
            connections=args.connections, radius=args.no_pvs, seed=args.seed, summary_every=args.summary_every,
            report=None, shards=args.shards, nats_nodes=args.nats_nodes, topology=None))
    start = time.perf_counter()

    def say(msg: str) -> None:
        print(f"[{time.perf_counter() - start:6.1f}s] {msg}", file=sys.stderr, flush=True)

    topo, path = bundled_topology(say, with_pvs=not args.no_pvs)
    c = topo.meta["counts"]
    print(
        f"Helsinki topology {path.name}: {c['edges']} edges, {topo.n_cells} cells, "
        f"{'PVS for ' + str(topo.meta['pvs']['view_cells']) + ' view cells' if 'pvs' in topo.meta else 'no PVS'}",
        flush=True,
    )
    config = DemoConfig(
        entities=args.entities, viewers=args.viewers, connections=args.connections, duration=args.duration,
        summary_every=args.summary_every, seed=args.seed, port=args.port, transit=args.transit,
        http_port=None if args.http_port < 0 else args.http_port, bus_share=0.03, tram_share=0.03,
    )  # fmt: skip
    try:
        trio.run(run_demo, topo, path, config, lambda m: print(m, flush=True))
    except* OSError as group:
        first = group.exceptions[0]
        while isinstance(first, BaseExceptionGroup):
            first = first.exceptions[0]
        raise CommandError(f"cannot listen: {first} (choose another --http-port, or 0 for any free port)") from None
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
    p.set_defaults(func=run_bench_command)


def progress(msg: str) -> None:
    """Bench progress goes to stderr so that stdout stays the results (pipe it into jq)."""
    print(f"[bench] {msg}", file=sys.stderr, flush=True)


def run_bench_command(args: argparse.Namespace) -> int:
    """Import the suite's module only now (a suite's heavy imports cost nothing to the other commands)."""
    from sims.bench import all_suites
    from sims.bench.report import write_report

    module = importlib.import_module(all_suites()[args.suite])
    body = module.run(args, progress)
    report = write_report(args.suite, body, args.out)
    print(json.dumps(report["results"], indent=2, default=float))
    if args.out:
        progress(f"report written to {args.out}")
    return 0
