"""`entitynet sim --workers N` / `--nats URL` and `entitynet sim worker`: the CLI's side of the workers.

Why here and not in `sims.sim_cmd`: the sim command only asks `make_sim` for its simulation and `close_sim`
to end it; everything about workers (the options, the default count, the transports, the worker daemon) lives
in this package. Heavy modules are imported inside the functions, so `entitynet --help` stays fast.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from entitynet.commands.options import bounded_float, bounded_int

#: below this many entities a run stays in one process by default (workers cost a world each: docs/simulation.md)
AUTO_MIN_ENTITIES = 2000


def add_options(p: argparse.ArgumentParser) -> None:
    """`--workers`, `--nats`, `--nats-token`, `--worker-timeout`, `--join-timeout` on `entitynet sim`, and its
    `worker` part."""
    p.add_argument("--workers", type=bounded_int(1, 256), metavar="N",
                   help="run the entities' honest clients in N worker processes (each steps the whole world from "
                        "the seed and runs the clients of a share of the entities; docs/simulation.md). Default: "
                        f"in this process below {AUTO_MIN_ENTITIES} entities or on 4 cores or fewer, else cores - 2 "
                        "(at most 8); with --nats: every worker that joins")
    p.add_argument("--nats", metavar="URL", help="take the workers from other machines over NATS (nats://HOST:PORT; "
                                                 "start `entitynet sim worker --nats URL` on each)")
    p.add_argument("--nats-token", default=None, metavar="TOKEN", help="with --nats: the NATS server's auth token")
    p.add_argument("--nats-connect-timeout", type=bounded_float(0.1, 60), default=1.0, metavar="S",
                   help="with --nats: how long one attempt to connect to a NATS server may take (default 1; a far "
                        "or slow server may need more)")
    p.add_argument("--worker-timeout", type=bounded_float(0.1, 600), default=10.0, metavar="S",
                   help="a worker that does not answer a tick within S seconds is declared dead and its entities "
                        "handed to the others (default 10)")
    p.add_argument("--join-timeout", type=bounded_float(0.1, 3600), default=30.0, metavar="S",
                   help="with --nats: how long to wait for the workers to join (default 30 s)")
    sub = p.add_subparsers(dest="sim_part", metavar="{worker}")
    w = sub.add_parser("worker", help="serve as a worker of `entitynet sim --nats URL` runs (on any machine)")
    w.add_argument("--nats", metavar="URL", required=True, help="the NATS server(s) of the coordinator")
    w.add_argument("--topology", metavar="FILE", help="topology artifact (default: the bundled Helsinki map); "
                                                      "must be the coordinator's")
    w.add_argument("--gtfs", metavar="FEED", help="GTFS zip (default: the coordinator's path if it exists here, "
                                                  "else the bundled HSL extract); must match the coordinator's")
    w.add_argument("--nats-token", default=None, metavar="TOKEN", help="the NATS server's auth token")
    w.add_argument("--nats-connect-timeout", type=bounded_float(0.1, 60), default=1.0, metavar="S",
                   help="how long one attempt to connect to a NATS server may take (default 1)")
    w.add_argument("--once", action="store_true", help="exit after one run")
    w.add_argument("--coordinator-silence", type=bounded_float(2.0, 3600), default=None, metavar="S",
                   help="give a run up when its coordinator has been silent this long, or for the run's "
                        "--worker-timeout if longer (default 5; at least 2: the coordinator says alive each second)")
    w.set_defaults(func=run_worker)


def auto_workers(entities: int, cpus: int | None) -> int | None:
    """The default worker count: None (one process) for a small run or a small machine, else cores - 2 (one
    core for the coordinator, one for the server), at most 8."""
    cpus = cpus or 1
    if entities < AUTO_MIN_ENTITIES or cpus <= 4:
        return None
    return min(cpus - 2, 8)


def check(args: argparse.Namespace) -> list[str]:
    """Problems with the worker options (for the command's one usage error)."""
    problems = []
    workers, nats = getattr(args, "workers", None), getattr(args, "nats", None)
    if getattr(args, "mobility", "ours") != "ours" and (workers or nats):
        problems.append("--workers and --nats need --mobility ours (a SUMO scenario runs in one process)")
    if nats:
        from entitynet.cluster.nats_client import parse_servers

        try:
            parse_servers(nats)
        except ValueError as exc:
            problems.append(f"--nats: {exc}")
    return problems


def make_sim(args: argparse.Namespace, topo, config, schedule, *, shards: int = 1, shard_at=None, source=None,
             say=print):
    """The run's simulation: `Sim` in this process, or `WorkerSim` over forked or NATS workers."""
    from sims.engine.sim import Sim

    workers, nats = getattr(args, "workers", None), getattr(args, "nats", None)  # a preset's own Namespace
    n = workers if workers is not None or nats else auto_workers(config.entities, os.cpu_count())
    if source is not None or (n is None and not nats):
        return Sim(topo, config, schedule, shards=shards, shard_at=shard_at, source=source)
    from sims.workers.sim import WorkerSim

    timeout = getattr(args, "worker_timeout", 10.0)
    if nats:
        from sims.workers.nats_link import NatsWorkers

        link = NatsWorkers(args.nats, token=getattr(args, "nats_token", None), say=say,
                           connect_timeout=getattr(args, "nats_connect_timeout", 1.0))
        try:
            names = link.choose(args.workers, args.join_timeout)
        except RuntimeError:
            link.close()
            raise
        say(f"{len(names)} worker(s) joined over NATS ({args.nats}): {', '.join(names)}")
        sim = WorkerSim(topo, config, schedule, link, len(names), transport=f"nats {args.nats}", timeout=timeout,
                        start_timeout=max(args.join_timeout, 60.0), run_id=link.run, reply=link.reply,
                        shards=shards, shard_at=shard_at, say=say)
        sim.core.digests.update(feed=str(args.gtfs or ""), date=str(args.date or ""))
        sim.join()  # here, not in the event loop: a refusal is one clear error (the caller closes the link)
        return sim
    from sims.workers.local import LocalWorkers

    link = LocalWorkers(n, topo, schedule)
    say(f"{n} worker process(es) on this machine (pids {', '.join(map(str, link.pids))})")
    sim = WorkerSim(topo, config, schedule, link, n, transport="local", timeout=timeout, shards=shards,
                    shard_at=shard_at, say=say)
    sim.join()
    return sim


def close_sim(sim) -> None:
    """End the workers of a `WorkerSim` (nothing for `Sim`): safe to call twice."""
    close = getattr(sim, "close", None)
    if callable(close) and not getattr(sim, "closed", False):
        sim.closed = True
        close()


def run_worker(args: argparse.Namespace) -> int:
    """`entitynet sim worker`: load the map, then serve runs over NATS until Ctrl-C (or one, with --once)."""
    import sys
    import time

    import trio

    from entitynet.cli import CommandError
    from entitynet.cluster.nats_client import parse_servers
    from entitynet.topology_cache import bundled_topology

    try:
        parse_servers(args.nats)
    except ValueError as exc:
        raise CommandError(f"--nats: {exc}") from None

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    if args.topology:
        from entitynet.commands.topology_cmd import load_artifact

        topo = load_artifact(args.topology)
    else:
        topo, _path = bundled_topology(say, with_pvs=True)
    build = share_builder(topo, args.gtfs)

    from sims.workers.nats_link import leaf_text, only, serve_worker
    from sims.workers.worker import SILENCE_MIN_S

    silence_min = SILENCE_MIN_S if args.coordinator_silence is None else args.coordinator_silence

    t0 = time.monotonic()
    try:
        runs = trio.run(lambda: serve_worker(args.nats, build, say, once=args.once, token=args.nats_token,
                                            connect_timeout=args.nats_connect_timeout, silence_min=silence_min))
    except BaseException as exc:  # noqa: BLE001 (one line for a NATS that cannot be reached, else re-raised)
        if only(exc, (OSError, trio.TooSlowError)) is None:
            raise
        raise CommandError(f"cannot reach NATS at {args.nats}: {leaf_text(exc)}") from None
    say(f"worker served {runs} run(s) in {time.monotonic() - t0:.0f} s")
    return 0


def share_builder(topo, gtfs: str | None, load=None):
    """A NATS worker's `build` (see `WorkerCore`): its share of a run from the assign's settings, with the
    schedule read from `gtfs` (else the coordinator's feed path where it exists here, else the bundled extract)
    and checked against the coordinator's digests. Why one schedule kept and not one per run: a worker daemon
    serves run after run, and each seed or service day is another schedule; the last one serves the usual
    repeated run, and memory stays bounded however many runs come. `load`: `load_schedule` (tests replace it)."""
    from entitynet.topology_cache import cache_dir
    from sims.engine.schedule import BUNDLED_FEED, GtfsError, load_schedule
    from sims.workers.run import RefusedRun, WorkerShare, config_from_wire, run_digests

    load = load or load_schedule
    kept: dict = {}  # at most one: (feed, date, seed) -> schedule

    def build(config: dict, want: dict, index: int, n: int) -> WorkerShare:
        cfg = config_from_wire(config)
        schedule = None
        if cfg.transit:
            theirs = want.get("feed") or ""
            feed = Path(gtfs) if gtfs else Path(theirs) if theirs and Path(theirs).is_file() else BUNDLED_FEED
            key = (str(feed), want.get("date") or None, cfg.seed)
            if key not in kept:
                kept.clear()
                try:
                    kept[key] = load(feed, topo, date=key[1], cache=cache_dir(), seed=cfg.seed)
                except (GtfsError, ValueError, OSError) as exc:
                    raise RefusedRun(f"cannot read the feed {feed}: {exc}") from None
            schedule = kept[key]
        mine = run_digests(topo, schedule)
        for key in ("topology", "schedule"):
            if want.get(key) != mine[key]:
                raise RefusedRun(f"another {key} than the coordinator's ({mine[key]} here, {want.get(key)} there): "
                                 "give this worker the same --topology / --gtfs")
        return WorkerShare(topo, schedule, cfg, index, n)

    return build
