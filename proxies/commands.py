"""`entitynet proxy siri | gtfs-rt | replay`: registered through the `entitynet.commands` entry-point group
(`entitynet` itself never imports `proxies`)."""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

from entitynet.commands.options import SEED, bounded_float, host_port, port, positive_seconds, time_of_day

log = logging.getLogger("proxies")


def _command_error(msg: str) -> Exception:
    from entitynet.cli import CommandError

    return CommandError(msg)


def register(sub) -> None:
    """Add `entitynet proxy siri|gtfs-rt|replay` to the CLI (found through the `entitynet.commands` entry
    point, so entitynet never imports proxies)."""
    p = sub.add_parser("proxy", help="transit proxies (SIRI, GTFS-realtime) and the SIRI replay producer")
    ps = p.add_subparsers(dest="proxy_command", metavar="KIND", required=True)

    s = ps.add_parser("siri", help="poll a SIRI StopMonitoring SOAP service and publish its vehicles")
    s.add_argument("--url", required=True, help="the SOAP service's address")
    s.add_argument("--wsdl", metavar="FILE_OR_URL", help="the operator's WSDL (default: our minimal one)")
    s.add_argument("--mode", choices=("auto", "multiple", "single"), default="auto",
                   help="GetMultipleStopMonitoring (all stops per request) or one GetStopMonitoring per stop")
    s.add_argument("--stops", metavar="FILE", help="stop ids to poll, one per line (default: every route stop)")
    _common(s)
    s.set_defaults(func=run_siri)

    g = ps.add_parser("gtfs-rt", help="poll GTFS-realtime feeds and publish their vehicles")
    g.add_argument("--vehicle-positions", metavar="URL", help="VehiclePositions feed")
    g.add_argument("--trip-updates", metavar="URL", help="TripUpdates feed")
    _common(g)
    g.set_defaults(func=run_gtfsrt)

    r = ps.add_parser("replay", help="serve SIRI StopMonitoring and GTFS-realtime from a GTFS schedule")
    r.add_argument("--gtfs", required=True, metavar="FEED", help="GTFS zip")
    r.add_argument("--host", default="127.0.0.1")
    r.add_argument("--port", type=port(), default=8080, help="HTTP port (default 8080; 0 = any free port)")
    r.add_argument("--start", type=time_of_day, default=8 * 3600.0, metavar="HH:MM[:SS]",
                   help="service time at startup (default 08:00:00); runs with the wall clock")
    r.add_argument("--delay-sigma", type=bounded_float(0, 3600),
                   default=90.0, metavar="S", help="spread of initial delays")
    r.add_argument("--step-sigma", type=bounded_float(0, 3600), default=20.0, metavar="S", help="delay change per stop")
    r.add_argument("--granularity", type=positive_seconds(3600),
                   default=60.0, metavar="S", help="ETA rounding (default 60 s)")
    r.add_argument("--latency", type=bounded_float(0, 60), default=0.0, metavar="S", help="seconds before every answer")
    r.add_argument("--fault-rate", type=bounded_float(0, 1),
                   default=0.0, metavar="R", help="fraction of answers that fail")
    r.add_argument("--locations", action="store_true", help="include VehicleLocation in SIRI answers")
    r.add_argument("--traced-bus-fraction", type=bounded_float(0, 1),
                   default=0.5, help="buses with a tracker (trams: all)")
    r.add_argument("--bbox", metavar="LON0,LAT0,LON1,LAT1", help="only trips stopping inside")
    r.add_argument("--topology", metavar="ART", help="only trips stopping on this map")
    r.add_argument("--truth", metavar="FILE.jsonl", help="record true positions here every second")
    r.add_argument("--seed", type=SEED, default=1)
    r.set_defaults(func=run_replay)


def _common(p) -> None:
    p.add_argument("--server", type=host_port, required=True, metavar="HOST:PORT", help="the switchboard")
    p.add_argument("--token", default="", help="auth token for the server")
    p.add_argument("--topology", metavar="ART", help="topology artifact (default: the bundled Helsinki map)")
    p.add_argument("--gtfs", required=True, metavar="FEED", help="GTFS schedule: routes and stops of the vehicles")
    p.add_argument("--poll", type=bounded_float(0.5, 86400),
                   default=20.0, metavar="S", help="seconds between polls (default 20)")
    p.add_argument("--timeout", type=bounded_float(0, 600, lo_open=True),
                   default=10.0, metavar="S", help="HTTP timeout (default 10)")
    p.add_argument("--stale-after", type=positive_seconds(86400), default=300.0, metavar="S",
                   help="retire a vehicle without news for this long (default 300)")
    p.add_argument("--metrics-port", type=port(), metavar="PORT", help="serve Prometheus /metrics here")
    p.add_argument("--duration", type=positive_seconds(), metavar="S", help="stop after this many seconds")
    p.add_argument("--unreachable-after", type=positive_seconds(86400), default=UNREACHABLE_AFTER, metavar="S",
                   help="say the server is unreachable after this many seconds without a first connection "
                        f"(default {UNREACHABLE_AFTER:g}; it keeps retrying)")


def _say(msg: str) -> None:
    print(f"[proxy] {msg}", file=sys.stderr, flush=True)


def _load(args):
    from topology.artifact import ArtifactError, load

    if args.topology:
        try:
            topo = load(args.topology)
        except (ArtifactError, OSError, ValueError) as exc:
            raise _command_error(f"cannot load topology {args.topology}: {exc}") from None
    else:
        from entitynet.topology_cache import bundled_topology

        topo, _path = bundled_topology(_say, with_pvs=False)
    if not Path(args.gtfs).exists():
        raise _command_error(f"GTFS feed {args.gtfs} not found")
    from proxies.routes import cached_routes

    t0 = time.perf_counter()
    try:
        book = cached_routes(topo, args.gtfs, say=_say)
    except ValueError as exc:  # the feed's readers' errors (GtfsError, ScheduleError) are ValueErrors
        raise _command_error(str(exc)) from None
    except OSError as exc:  # a folder, a file that cannot be read
        raise _command_error(f"cannot read GTFS feed {args.gtfs}: {exc.strerror or exc}") from None
    _say(f"{len(book.routes)} trips on {len({id(r) for r in book.routes.values()})} routes over the map, "
         f"{len(book.stops)} stops ({time.perf_counter() - t0:.1f} s)")
    if not book.routes:
        raise _command_error("no trip of the GTFS feed runs over the map")
    return topo, book


def _run_shell(args, topo, book, make_poller) -> int:
    import trio

    from proxies.shell import ProxyConfig, ProxyShell

    cfg = ProxyConfig(args.server, args.token, args.poll, 1.0, args.timeout, args.stale_after)
    shell = ProxyShell(topo, book, cfg)
    if args.metrics_port is not None:
        from prometheus_client import start_http_server

        from entitynet.server.config import ListenError, bind_reason

        try:
            start_http_server(args.metrics_port, addr="127.0.0.1", registry=shell.metrics.registry)
        except OSError as exc:  # the port in use, or not ours to bind
            raise _command_error(str(ListenError("metrics_port", "127.0.0.1", args.metrics_port,
                                                 bind_reason(exc)))) from None

    async def main():
        async with trio.open_nursery() as n:
            start = time.monotonic()  # before the first connection: an unreachable server must not stop the clock
            n.start_soon(shell.run, make_poller(shell))
            n.start_soon(_say_while_unreachable, shell, "{}:{}".format(*args.server),
                         getattr(args, "unreachable_after", UNREACHABLE_AFTER))
            while args.duration is None or time.monotonic() - start < args.duration:
                await trio.sleep(min(10.0, args.duration or 10.0))
                c = shell.fleet.counters
                _say(f"vehicles {len(shell.fleet.vehicles)} | polls {c.polls} | discarded "
                     f"{c.discarded_fraction:.1%} | publishes {c.publishes} | last error {shell.last_error}")
            n.cancel_scope.cancel()

    from entitynet.cli import leaves
    from entitynet.connection import HandshakeRefused
    from entitynet.interrupts import run_until_interrupted

    refused = None
    try:
        run_until_interrupted(main)
    except BaseException as exc:  # noqa: B036 - only a refusal (maybe inside exception groups) is ours to report
        refused = next((e for e in leaves(exc) if isinstance(e, HandshakeRefused)), None)
        if refused is None:
            raise
    if refused is not None:
        raise _command_error(str(refused))
    return 0


#: seconds without a first connection before the proxy says the server is unreachable, then between repeats
UNREACHABLE_AFTER, UNREACHABLE_REPEAT = 5.0, 300.0


async def _say_while_unreachable(shell, server: str, after: float = UNREACHABLE_AFTER) -> None:
    """One line when the server has not answered after `after` seconds (`--unreachable-after`; the connection
    keeps retrying by itself), then rarely while it stays so: before, a proxy of an unreachable server ran
    silently forever."""
    import trio

    waited = after
    await trio.sleep(after)
    while shell.conn.connects == 0:
        _say(f"server {server} unreachable, retrying" + (f" ({waited:.0f} s)" if waited > after else ""))
        await trio.sleep(UNREACHABLE_REPEAT)
        waited += UNREACHABLE_REPEAT


def run_siri(args) -> int:
    """`entitynet proxy siri`: poll a SIRI StopMonitoring service for the map's stops (or those of
    `--stops`) and publish its vehicles until stopped."""
    from proxies.siri_client import StopMonitoringClient
    from proxies.siri_xml import SiriError

    topo, book = _load(args)
    if args.stops:
        try:
            wanted = [ln.strip() for ln in Path(args.stops).read_text().splitlines() if ln.strip()]
        except OSError as exc:
            raise _command_error(f"cannot read {args.stops}: {exc}") from None
        book.stops = wanted
    try:
        client = StopMonitoringClient(args.url, args.wsdl, timeout=args.timeout, mode=args.mode)
    except SiriError as exc:
        raise _command_error(str(exc)) from None
    _say(f"{client.mode} StopMonitoring on {args.url}: {client.requests_for(book.stops)} request(s) per poll")
    return _run_shell(args, topo, book, lambda shell: shell.siri_poller(client))


def run_gtfsrt(args) -> int:
    """`entitynet proxy gtfs-rt`: poll GTFS-realtime VehiclePositions and/or TripUpdates and publish the
    vehicles; at least one feed URL is required."""
    if not (args.vehicle_positions or args.trip_updates):
        raise _command_error("give --vehicle-positions URL and/or --trip-updates URL")
    topo, book = _load(args)
    return _run_shell(args, topo, book,
                      lambda shell: shell.gtfsrt_poller(args.vehicle_positions, args.trip_updates))


def run_replay(args) -> int:
    """`entitynet proxy replay`: serve a schedule's simulated vehicles as SIRI (and GTFS-rt), with
    optional latency and faults, so a proxy can be tried and measured without a real operator."""
    import trio

    from proxies.replay_core import ReplayWorld
    from proxies.replay_http import ReplayConfig, ReplayService, record_truth, wall_service_clock
    from proxies.schedule import ScheduleError, read_schedule
    from proxies.siri_xml import ServiceClock

    if not 0.0 <= args.fault_rate <= 1.0:
        raise _command_error("--fault-rate must be between 0 and 1")
    if args.latency < 0 or args.granularity < 0:
        raise _command_error("--latency and --granularity must be >= 0")
    bbox = None
    if args.bbox:
        try:
            bbox = tuple(float(v) for v in args.bbox.split(","))
            assert len(bbox) == 4
        except (ValueError, AssertionError):
            raise _command_error(f"--bbox wants LON0,LAT0,LON1,LAT1, got {args.bbox!r}") from None
    elif args.topology:
        import numpy as np

        from topology.artifact import ArtifactError, load
        from topology.projection import LocalProjection

        try:
            topo = load(args.topology)
        except (ArtifactError, OSError, ValueError) as exc:
            raise _command_error(f"cannot load topology {args.topology}: {exc}") from None
        x0, y0, x1, y1 = topo.meta["bounds"]
        ll = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"])).to_wgs84(
            np.array([[x0, y0], [x1, y1]], dtype=np.float64))
        bbox = (float(ll[:, 0].min()), float(ll[:, 1].min()), float(ll[:, 0].max()), float(ll[:, 1].max()))
    t0 = time.perf_counter()
    try:
        sched = read_schedule(args.gtfs, bbox=bbox)
    except ScheduleError as exc:
        raise _command_error(str(exc)) from None
    world = ReplayWorld(sched, seed=args.seed, delay_sigma=args.delay_sigma, step_sigma=args.step_sigma,
                        granularity=args.granularity, traced_bus_fraction=args.traced_bus_fraction,
                        locations=args.locations)
    clock = ServiceClock.for_date(sched.service_date)
    cfg = ReplayConfig(args.host, args.port, args.latency, args.fault_rate, seed=args.seed)
    service = ReplayService(world, clock, wall_service_clock(args.start), cfg)

    async def main():
        async with trio.open_nursery() as n:
            await n.start(service.serve)
            _say(f"replay of {len(world.runs)} departures ({time.perf_counter() - t0:.1f} s to load) on "
                 f"http://{args.host}:{service.port}/siri and /gtfs-rt/vehicle-positions, /gtfs-rt/trip-updates")
            if args.truth:
                n.start_soon(record_truth, service, args.truth)

    from entitynet.interrupts import run_until_interrupted

    run_until_interrupted(main)  # a Ctrl-C anywhere in the run is a clean stop (status 130)
    return 0
