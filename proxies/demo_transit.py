"""Transit for `entitynet demo --transit FEED`: the replay producer and the SIRI proxy in the demo's process,
feeding its server (replay -> SOAP over loopback HTTP -> proxy -> server), so the demo's viewers see trams and
buses moved from one-minute ETAs exactly as a real agency's feed would move them."""

from __future__ import annotations

import time
from collections.abc import Callable

import trio

from proxies.replay_core import ReplayWorld
from proxies.replay_http import ReplayConfig, ReplayService, wall_service_clock
from proxies.routes import RouteBook, cached_routes
from proxies.shell import ProxyConfig, ProxyShell
from proxies.siri_client import StopMonitoringClient
from proxies.siri_xml import ServiceClock


async def run_transit(topo, address: tuple[str, int], feed, say: Callable[[str], None], *, poll: float = 10.0,
                      start: float = 8 * 3600.0, book: RouteBook | None = None,
                      clock: Callable[[], float] = time.time, task_status=trio.TASK_STATUS_IGNORED) -> None:
    """Start the replay (service time from `start`, with the wall clock) and the proxy; runs until cancelled.
    `clock`: the proxy's clock, the one its vehicles' models are stamped with (the demo passes its server's,
    the simulation's, so that a viewer extrapolates them in the same time as the simulated entities).
    `task_status.started(shell)` once both listen."""
    if book is None:
        book = await trio.to_thread.run_sync(lambda: _routes(topo, feed, say))
    if not book.routes:
        say(f"warning: no trip of {feed} runs over the map: the feed does not overlap the map (a feed of another "
            "city?); the demo has no trams or buses")
    world = ReplayWorld(book.schedule, granularity=60.0)
    service = ReplayService(world, ServiceClock.for_date(book.schedule.service_date), wall_service_clock(start),
                            ReplayConfig(port=0, latency=2.0))
    async with trio.open_nursery() as n:
        await n.start(service.serve)
        client = await trio.to_thread.run_sync(
            lambda: StopMonitoringClient(f"http://127.0.0.1:{service.port}/siri", timeout=10.0))
        shell = ProxyShell(topo, book, ProxyConfig(address, poll=poll), clock=clock)
        await n.start(shell.run, shell.siri_poller(client))
        say(f"transit: replay of {len(world.runs)} departures on http://127.0.0.1:{service.port}/siri, "
            f"SIRI proxy polling {len(book.stops)} stops every {poll:.0f} s")
        task_status.started(shell)


def _routes(topo, feed, say: Callable[[str], None]) -> RouteBook:
    """The feed's routes on the map; a feed that cannot be read is the command's error (one line, no traceback),
    not a crash of the demo."""
    from entitynet.cli import CommandError

    try:
        return cached_routes(topo, feed, say=say)
    except ValueError as exc:  # the GTFS readers' errors
        raise CommandError(f"--transit {feed}: {exc}") from None
    except OSError as exc:
        raise CommandError(f"--transit {feed}: cannot read the feed ({exc.strerror or exc})") from None
