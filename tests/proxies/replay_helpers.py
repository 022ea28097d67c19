"""A replay producer on loopback for the proxy tests (real HTTP on 127.0.0.1)."""

from __future__ import annotations

import contextlib

import trio

from proxies.replay_core import ReplayWorld
from proxies.replay_http import ReplayConfig, ReplayService, wall_service_clock
from proxies.schedule import read_schedule
from proxies.siri_xml import ServiceClock


def make_service(feed, *, start: float = 8 * 3600 + 600.0, modes=("tram",), world_kw=None, **cfg) -> ReplayService:
    sched = read_schedule(feed, modes=modes)
    world = ReplayWorld(sched, **(world_kw or {}))
    return ReplayService(world, ServiceClock.for_date(sched.service_date), wall_service_clock(start),
                         ReplayConfig(port=0, **cfg))


@contextlib.asynccontextmanager
async def replay_running(service: ReplayService):
    async with trio.open_nursery() as n:
        await n.start(service.serve)
        try:
            yield service
        finally:
            n.cancel_scope.cancel()


def url(service: ReplayService, path: str = "/siri") -> str:
    return f"http://127.0.0.1:{service.port}{path}"
