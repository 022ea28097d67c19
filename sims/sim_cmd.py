"""`entitynet sim`: a city simulation through honest clients, with a live summary and a JSON report.

Registered by `entitynet.cli` (for now by name in COMMAND_MODULES; at merge through the "entitynet.commands"
entry-point group). Everything heavy is imported inside `run`, so `entitynet --help` stays fast.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from entitynet.commands.options import SEED, bounded_float, bounded_int, host_port, positive_seconds, time_of_day
from sims.engine import TICK_HZ_RANGE


def register(sub) -> None:
    """Add the `sim` subcommand and its options to the CLI's subparsers (called by `entitynet.cli`)."""
    p = sub.add_parser("sim", help="simulate a city (pedestrians, cars, scheduled buses and trams) through honest "
                                   "clients and PVS viewers, with a live summary and a JSON report",
                       epilog="How large a run keeps real time: on a quiet 2-core machine about 5,200 entities "
                              "with 520 viewers, the server in a child process (from 1,000 entities or 100 viewers "
                              "at --speed 1 or more, --server-process), 4,800 with it in this process, and 8,000 "
                              "with 800 viewers of which a tenth keep ghosts and are measured (--measured-viewers), "
                              "the viewers in this process as in entitynet bench sim's ladders (--viewer-processes "
                              "0; docs/simulation.md). A larger run still steps every tick, late: "
                              "the live summary shows the tick lateness, and a warning says when the run falls "
                              "behind (then every 30 s while it lasts). --speed 0.5 halves the load.")
    p.add_argument("--entities", type=bounded_int(0, 1_000_000),
                   default=300, help="pedestrians and cars on the map (default 300)")
    p.add_argument("--car-share", type=bounded_float(0, 1), default=0.3, help="share of cars among them (default 0.3)")
    p.add_argument("--viewers", type=bounded_int(0, 100_000),
                   default=24, help="viewers (default 24, a quarter above the roofs)")
    p.add_argument("--gtfs", metavar="FEED", help="GTFS zip for the trams and buses (default: the bundled HSL "
                                                  "extract); 'none' for no transit")
    p.add_argument("--date", metavar="YYYYMMDD", help="service day of the feed (default: its busiest)")
    p.add_argument("--start", type=time_of_day, default=8 * 3600.0, metavar="HH:MM",
                   help="service-day time the run starts at (default 08:00)")
    p.add_argument("--duration", type=positive_seconds(), help="simulated seconds to run (default: until Ctrl-C)")
    p.add_argument("--speed", type=bounded_float(0, 1000, lo_open=True),
                   default=1.0, help="times real time (default 1; e.g. 10)")
    p.add_argument("--tick-hz", type=bounded_float(*TICK_HZ_RANGE),
                   default=2.0, help="simulation ticks per second (default 2)")
    p.add_argument("--server", type=host_port, metavar="HOST:PORT",
                   help="an existing shard server (default: start one in this process)")
    p.add_argument("--token", default="", help="auth token for --server")
    p.add_argument("--server-process", choices=("auto", "yes", "no"), default="auto",
                   help="run the shard server in a child process (`entitynet serve`, the second core) instead of "
                        "this one; auto (the default): from 1000 entities or 100 viewers at --speed 1 or more "
                        "(docs/simulation.md)")
    p.add_argument("--shards", type=bounded_int(1, 64),
                   metavar="K", help="start a local cluster of K switchboard processes "
                   "joined by nats-server and run against it (entities and viewers by where they are)")
    p.add_argument("--nats-nodes", type=bounded_int(1, 16),
                   default=1, metavar="N", help="nats-server nodes with --shards "
                                                                           "(default 1)")
    p.add_argument("--topology", metavar="FILE", help="topology artifact (default: the bundled Helsinki map)")
    p.add_argument("--connections", type=bounded_int(1, 1024),
                   default=4, help="connections carrying the entities (default 4)")
    p.add_argument("--radius", action="store_true", help="viewers subscribe to a 500 m radius instead of the PVS")
    p.add_argument("--measure-share", type=bounded_float(0, 1, lo_open=True), default=0.25, metavar="S",
                   help="share of the viewers measured against the truth at each 1 s sample, in turn (default "
                        "0.25: each viewer every 4 s, so the measure does not make real time late); 1 = the full "
                        "measure")
    p.add_argument("--measured-viewers", type=bounded_int(1, 1_000_000), metavar="K",
                   help="only K of the viewers (spread evenly, street and roof alike) keep ghosts and enter the "
                        "truth figures; the others connect, subscribe and read every byte (the server's load is "
                        "unchanged) but only count UPDATEs, LEAVEs and bytes (default: all measured; the report's "
                        "truth_vs_viewer says how many it rests on; docs/simulation.md)")
    p.add_argument("--viewer-processes", type=bounded_int(0, 64), metavar="K",
                   help="run the viewers in K processes of their own, each with its share of the viewers, their "
                        "server connections and their measure against the truth it steps from the seed (0: in "
                        "this process; default: on 2-4 cores 1 from 200 viewers on, else 0; on more cores one per "
                        "250 viewers up to cores - 2; "
                        "not with --shards or --mobility sumo; docs/simulation.md)")
    p.add_argument("--seed", type=SEED, default=1, help="random seed (default 1)")
    p.add_argument("--summary-every", type=positive_seconds(86400),
                   default=5.0, metavar="S", help="summary interval (default 5 s)")
    p.add_argument("--report", metavar="FILE.json", help="write the final JSON report here (default: stdout)")
    p.add_argument("--mobility", choices=("ours", "sumo"), default="ours",
                   help="what moves the entities: our world model (default) or an Eclipse SUMO scenario stepped "
                        "in process (needs the [sumo] extra; docs/sumo.md)")
    p.add_argument("--sumocfg", metavar="FILE", help="with --mobility sumo: the scenario's .sumocfg (default: the "
                   "bundled map's scenario, generated once by `entitynet sumo scenario` and cached)")
    p.set_defaults(func=run)
    from sims.workers.commands import add_options

    add_options(p)  # --workers, --nats, ... and `entitynet sim worker`


def sim_args(**overrides) -> argparse.Namespace:
    """`entitynet sim`'s options as its parser sets them by default, with `overrides` (names of its options).

    Why through the parser: a preset (`entitynet demo --shards K`) that wrote out its own Namespace missed every
    option added to `sim` after it (`--measure-share` crashed the demo); an override that names no option of
    `sim` is a TypeError here, not an AttributeError deep inside the run."""
    parser = argparse.ArgumentParser(prog="entitynet")
    register(parser.add_subparsers())
    args = parser.parse_args(["sim"])
    for name, value in overrides.items():
        if not hasattr(args, name):
            raise TypeError(f"entitynet sim has no option {name!r}")
        setattr(args, name, value)
    return args


def run(args: argparse.Namespace) -> int:
    """Check the options (clear usage errors before anything loads), load the topology and schedule, run the
    shell and write the JSON report; 0 on success."""
    from entitynet.cli import CommandError

    problems = []
    if args.duration is not None and not args.duration > 0:
        problems.append("--duration must be a positive number of seconds")
    if not args.speed > 0:
        problems.append("--speed must be positive")
    if not args.summary_every > 0:
        problems.append("--summary-every must be positive")
    if args.gtfs not in (None, "none") and not Path(args.gtfs).is_file():
        problems.append(f"{args.gtfs}: cannot read the feed (no such file)")
    if args.shards is not None and not 1 <= args.shards <= 64:
        problems.append("--shards must be between 1 and 64")
    if args.shards is not None and args.server is not None:
        problems.append("--shards starts its own cluster: give either --shards or --server")
    if args.nats_nodes < 1:
        problems.append("--nats-nodes must be at least 1")
    if getattr(args, "sumocfg", None) and getattr(args, "mobility", "ours") != "sumo":
        problems.append("--sumocfg needs --mobility sumo")
    from sims.server_child import wants_server_process

    try:
        child_server, child_why = wants_server_process(args.server_process, args.entities, args.viewers, args.speed,
                                                       external=args.server is not None or args.shards is not None)
    except ValueError as exc:
        problems.append(str(exc))
    from sims.workers.commands import check as check_workers

    problems += check_workers(args)
    viewer_procs = getattr(args, "viewer_processes", None)  # a preset's own Namespace may not have it
    if viewer_procs is None:  # the default never forks where viewer processes cannot run (refused below)
        unsupported = args.shards is not None or getattr(args, "mobility", "ours") == "sumo"
        viewer_procs = 0 if unsupported else auto_viewer_processes(args.viewers, os.cpu_count())
    elif viewer_procs > args.viewers:
        problems.append(f"--viewer-processes {viewer_procs} is more than the {args.viewers} viewers")
    if viewer_procs and args.shards is not None:
        problems.append("--viewer-processes does not go with --shards (a cluster's viewers follow their cameras "
                        "between shards)")
    if viewer_procs and getattr(args, "mobility", "ours") == "sumo":
        problems.append("--viewer-processes steps our world model for the truth: not with --mobility sumo")
    if problems:
        raise CommandError("; ".join(problems))

    from entitynet.topology_cache import bundled_topology
    from sims.engine.sim import SimConfig

    t0 = time.perf_counter()

    def say(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    try:
        config = SimConfig(entities=args.entities, viewers=args.viewers, connections=args.connections,
                           car_share=args.car_share, tick_hz=args.tick_hz, seed=args.seed, start=args.start,
                           transit=args.gtfs != "none", subscribe="radius" if args.radius else "pvs",
                           measure_share=args.measure_share,
                           measured_viewers=getattr(args, "measured_viewers", None))
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    if not 0 <= args.car_share <= 1:
        raise CommandError("--car-share must be within 0..1")
    if args.entities < 0:
        raise CommandError("--entities must be at least 0")
    if args.topology:
        from entitynet.commands.topology_cmd import load_artifact

        topo, path = load_artifact(args.topology), Path(args.topology)
    else:
        topo, path = bundled_topology(lambda m: say(f"[{time.perf_counter() - t0:6.1f}s] {m}"), with_pvs=True)
    source = None
    if getattr(args, "mobility", "ours") == "sumo":  # SUMO moves everyone: no population, no schedule of ours
        from sims.sumo.commands import sumo_source

        source = sumo_source(topo, args.sumocfg, config, say)
        config.transit, config.entities = False, 0
    schedule = load_feed(args.gtfs, topo, args.date, args.seed, config.start, say) if config.transit else None
    regions = shard_at = None
    if args.shards:
        from sims.cluster_run import shard_locator
        from topology.regions import RegionError, build_regions

        try:
            regions = build_regions(topo, args.shards)
        except RegionError as exc:
            raise CommandError(str(exc)) from None
        shard_at = shard_locator(topo, regions)
    from sims.workers.commands import close_sim, make_sim

    try:
        sim = make_sim(args, topo, config, schedule, shards=args.shards or 1, shard_at=shard_at, source=source,
                       say=say)
    except (RuntimeError, ValueError) as exc:
        raise CommandError(str(exc)) from None
    vp = None
    try:
        if viewer_procs:  # forked here, before any event loop runs, with the map and schedule loaded
            from sims.viewers.procs import ViewerProcesses

            vp = ViewerProcesses(viewer_procs, topo, schedule, config)
        return _run_sim(args, sim, config, path, topo, regions, child_server, child_why, say, vp)
    finally:
        if vp is not None:
            vp.close()
        close_sim(sim)


SMALL_MACHINE_VIEWERS = 200  # on 2-4 cores, one viewer process from this many viewers on


def auto_viewer_processes(viewers: int, cores: int | None) -> int:
    """The default of `--viewer-processes`: on 2-4 cores one process from `SMALL_MACHINE_VIEWERS` viewers on (the
    coordinator then keeps real time to larger runs: measured on a quiet 2-core machine, docs/simulation.md,
    "Viewer processes"), else none; on more cores one process per 250 viewers, at most cores - 2; on one core
    none (the processes would only take turns)."""
    cores = cores or 1
    if cores <= 1:
        return 0
    if cores <= 4:
        return 1 if viewers >= SMALL_MACHINE_VIEWERS else 0
    if viewers < 250:
        return 0
    return min(viewers // 250, cores - 2)


def _run_sim(args, sim, config, path: Path, topo, regions, child_server: bool, child_why: str, say,
             viewer_procs=None) -> int:
    """The run itself, once the simulation is built (its workers, if any, are ended by the caller)."""
    import trio

    from sims.shell import Shell, ShellConfig

    say(f"{sum(sim.world.by_type().values()) if sim.world.agents else config.entities} entities, "
        f"{len(sim.viewers)} viewers subscribing by {sim.subscription_text()}, ticks at {config.tick_hz:g} Hz, "
        f"speed x{args.speed:g}")
    if config.measured_viewers is not None and config.measured_viewers < config.viewers:
        say(f"{config.measured_viewers} viewers measured against the truth, {config.viewers - config.measured_viewers}"
            " counted (they subscribe and read every byte, but keep no ghosts): the truth figures rest on "
            f"{config.measured_viewers}")
    if viewer_procs is not None:
        sim.viewers = []  # they live in the viewer processes
        pids = ", ".join(map(str, viewer_procs.pids))
        say(f"viewers in {viewer_procs.n} processes of their own (pids {pids}), each measuring its share against "
            "the truth" if viewer_procs.n > 1 else
            f"viewers in a process of their own (pid {pids}), measuring them against the truth")
    shell = Shell(sim, ShellConfig(duration=args.duration, speed=args.speed, summary_every=args.summary_every,
                                   server=args.server, token=args.token, artifact=path,
                                   viewer_processes=viewer_procs, settle_gc=True), say)
    shell.server_info = {"process": child_server, "why": child_why}
    if child_server:
        report = _on_child_server(shell, path, child_why, say)
    elif regions is None:
        report = trio.run(shell.run)
    else:
        report = trio.run(_on_cluster, shell, topo, path, regions, args.nats_nodes, say)
        if report is None:
            say("interrupted before the simulation began; the cluster is stopped")
            return 130
    emit_report(report, args.report, say)
    return run_status(sim, say)


def run_status(sim, say) -> int:
    """The exit status of a finished run: 1 when it ended early (every worker gone: the report is written, but a
    script must not take it for a whole run), else 0."""
    why = getattr(sim, "ended_early", None)
    if why:
        say(f"the run ended early: {why}")
        return 1
    return 0


def _on_child_server(shell, path: Path, why: str, say) -> dict:
    """Run the shell against a child `entitynet serve` that lives exactly as long as the run (sims.server_child):
    stopped on the way out whatever the way (the end, Ctrl-C, an error); a child that dies mid-run is one clear
    error line naming its last log lines."""
    import trio

    from entitynet.cli import CommandError
    from sims.server_child import ServerChild, ServerChildDied

    try:
        with ServerChild(path) as child:
            host, port = shell.config.server = child.address
            shell.server_info = child.report(why)
            say(f"shard server listening on {host}:{port} (a child process, pid {child.pid}: {why})")
            return trio.run(child.run_shell, shell)
    except ServerChildDied as exc:
        raise CommandError(str(exc)) from None


async def _on_cluster(shell, topo, path: Path, regions, nats_nodes: int, say) -> dict | None:
    """Run the shell against a local cluster that lives exactly as long as the run (sims.cluster_run); None
    when Ctrl-C (or SIGTERM) came before the run began. Why the signal receiver: an interrupt while the cluster
    starts must still tear it down in order, not surface as a KeyboardInterrupt in whichever task ran."""
    import signal

    import trio

    from entitynet.cli import CommandError
    from sims.cluster_run import local_cluster

    report = None

    async def cancel_on_signal(signals, scope: trio.CancelScope) -> None:
        async for _sig in signals:
            scope.cancel()
            return

    try:
        with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:  # from the very start
            async with trio.open_nursery() as nursery:
                nursery.start_soon(cancel_on_signal, signals, nursery.cancel_scope)
                async with local_cluster(topo, path, regions, nats_nodes, say) as cluster:
                    shell.config.cluster = cluster
                    report = await shell.run()  # its own receiver takes the signals while it runs
                nursery.cancel_scope.cancel()
    except RuntimeError as exc:
        raise CommandError(str(exc)) from None
    return report


def emit_report(report: dict, path: str | None, say) -> None:
    """The final JSON report: to `path`, or to stdout (the live summary goes to stderr, so stdout pipes into
    jq). Shared by `entitynet sim` and `entitynet demo`."""
    text = json.dumps(report, indent=2, default=float)
    if path:
        Path(path).write_text(text + "\n")
        say(f"report written to {path}")
    else:
        print(text, flush=True)


def load_feed(gtfs: str | None, topo, date: str | None, seed: int, start: float, say):
    """The schedule of `gtfs` (None: the bundled HSL extract) on the map, cached; a clear CommandError for a
    feed that cannot be used. Shared by `entitynet sim` and `entitynet demo`."""
    from entitynet.cli import CommandError
    from entitynet.topology_cache import cache_dir
    from sims.engine.schedule import BUNDLED_FEED, GtfsError, load_schedule

    feed = Path(gtfs) if gtfs else BUNDLED_FEED
    try:
        schedule = load_schedule(feed, topo, date=date, cache=cache_dir(), seed=seed)
    except (GtfsError, ValueError) as exc:
        raise CommandError(str(exc)) from None
    n_run = len(schedule.running_at(start))
    say(f"schedule {feed.name} (service day {schedule.service_date or 'any'}): "
        f"{len(schedule.departures)} departures over the map, {n_run} under way at the start")
    if not schedule.departures:
        say(f"warning: {no_departures_reason(feed.name, schedule)}; the run has no scheduled trams or buses")
    return schedule


def no_departures_reason(name: str, schedule) -> str:
    """Why a feed put no departure on the map, from its read report: a feed of another city (its trips in
    service all run off the map) reads differently from a day without service. Why a warning of its own: "0
    departures over the map" went by unnoticed in the middle of the start-up lines."""
    report = schedule.report
    off_map = int(report.get("skipped:trip_off_map", 0))
    if off_map:
        return (f"the feed {name} does not overlap the map: none of its {off_map} trams' and buses' trips in "
                "service runs over it (a feed of another city?)")
    if report.get("skipped:not_in_service", 0):
        return f"no tram or bus trip of {name} is in service on {schedule.service_date or 'the chosen day'}"
    return f"the feed {name} has no tram or bus trip that runs over the map"
