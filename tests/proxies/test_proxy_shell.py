"""The proxies end to end on loopback: replay producer (real HTTP) -> proxy shell -> real server -> a viewer.
Every fault of the tracker is injected through the replay's /control endpoint."""

from __future__ import annotations

import threading
import time

import requests
import trio

from entitynet import protocol as P
from proxies.shell import ProxyConfig, ProxyShell
from proxies.siri_client import StopMonitoringClient
from tests.entitynet.server_helpers import Raw, running
from tests.proxies.replay_helpers import make_service, replay_running, url


async def _viewer(server, topo) -> Raw:
    v = await Raw.connect(server, digest=topo.digest)
    await v.send(P.Subscribe(tuple(range(topo.n_cells)), ()))
    await v.send(P.Ping(1))
    await v.expect(P.Pong)
    return v


async def _updates(v: Raw, seconds: float) -> tuple[set[int], set[int]]:
    """Entities updated and entities that left, over `seconds`."""
    upd, left = set(), set()
    with trio.move_on_after(seconds):
        while True:
            msgs = await v.read(seconds)
            if msgs is None:
                break
            for m in msgs:
                if isinstance(m, P.Update):
                    upd.add(m.entity)
                elif isinstance(m, P.Leave):
                    left.add(m.entity)
    return upd, left


async def _an_update(v: Raw, seconds: float = 30.0) -> bool:
    """Whether the viewer reads an UPDATE within `seconds` (a deadline for a hang): returns at the first."""
    with trio.move_on_after(seconds):
        while True:
            msgs = await v.read(seconds)
            if msgs is None:
                return False
            if any(isinstance(m, P.Update) for m in msgs):
                return True
    return False


async def _control(service, query: str) -> None:
    r = await trio.to_thread.run_sync(requests.post, url(service, f"/control?{query}"))
    assert r.status_code == 200


def _shell(topo, book, server, **kw) -> ProxyShell:
    cfg = ProxyConfig(("127.0.0.1", server.port), poll=kw.pop("poll", 0.3), tick=0.2, timeout=kw.pop("timeout", 2.0),
                      stale_after=kw.pop("stale_after", 300.0))
    return ProxyShell(topo, book, cfg)


async def _wait(pred, seconds: float = 30.0) -> None:
    """Until `pred()` holds; `seconds` is a deadline for a hang, generous for a loaded CI machine."""
    with trio.fail_after(seconds):
        while not pred():
            await trio.sleep(0.05)


async def test_siri_proxy_publishes_vehicles_and_survives_every_fault(line_topo, line_book, line_feed):
    service = make_service(line_feed, slow_s=3.0)
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server, replay_running(service):
        viewer = await _viewer(server, line_topo)
        shell = _shell(line_topo, line_book, server, timeout=1.0, poll=0.1)  # (each fault takes 2 polls and 1 good)
        client = StopMonitoringClient(url(service), mode="multiple", timeout=1.0)
        async with trio.open_nursery() as n:
            await n.start(shell.run, shell.siri_poller(client))
            await _wait(lambda: len(shell.fleet.vehicles) >= 3)
            upd, _ = await _updates(viewer, 1.0)
            assert len(upd) >= 3  # the vehicles reach a viewer through the server
            before = set(shell.fleet.vehicles)
            for fault, kind in [("soap", "soap_fault"), ("http500", "http_5xx"), ("http404", "http_4xx"),
                                ("garbage", "malformed"), ("truncated", "malformed"), ("slow", "timeout")]:
                good = shell.good_polls
                await _control(service, f"fault={fault}&count=2")
                await _wait(lambda kind=kind: shell.metrics.value("entitynet_proxy_errors_total", kind=kind) >= 2)
                await _wait(lambda good=good: shell.good_polls > good)  # recovered, no restart
            # an empty delivery is an answer: the vehicles carry on, nothing counted as an error
            good = shell.good_polls
            await _control(service, "fault=empty&count=2")
            await _wait(lambda: shell.good_polls >= good + 3)  # the two empty deliveries and a full one
            assert before & set(shell.fleet.vehicles)
            assert shell.fleet.counters.retired_stale == 0  # nobody lost over the faults
            assert await _an_update(viewer)  # still reaching the viewer after all that
            assert 0.0 < shell.fleet.counters.discarded_fraction < 1.0
            assert shell.metrics.value("entitynet_proxy_publishes_total") > 0
            n.cancel_scope.cancel()


async def test_an_outage_keeps_vehicles_moving_and_stale_ones_leave_then_come_back(line_topo, line_book, line_feed):
    service = make_service(line_feed)
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server, replay_running(service):
        viewer = await _viewer(server, line_topo)
        shell = _shell(line_topo, line_book, server, stale_after=2.0)
        client = StopMonitoringClient(url(service), mode="multiple", timeout=1.0)
        async with trio.open_nursery() as n:
            await n.start(shell.run, shell.siri_poller(client))
            await _wait(lambda: len(shell.fleet.vehicles) >= 3)
            moving = {r: v.motion.s for r, v in shell.fleet.vehicles.items() if not v.motion.standing}
            await _control(service, "outage=4")
            await trio.sleep(1.2)  # within stale_after: still on the map, still moving on their ETAs
            still = {r: v.motion.s for r, v in shell.fleet.vehicles.items() if r in moving}
            assert still and any(still[r] > moving[r] for r in still)
            upd, left = await _updates(viewer, 2.5)  # past stale_after: they leave
            assert left and shell.fleet.counters.retired_stale > 0
            assert shell.metrics.value("entitynet_proxy_errors_total", kind="http_5xx") >= 2
            await _wait(lambda: len(shell.fleet.vehicles) >= 3, 30.0)  # the outage ends: back without a restart
            upd, _ = await _updates(viewer, 1.0)
            assert upd
            n.cancel_scope.cancel()


async def test_a_server_that_goes_away_is_reconnected_and_the_fleet_republished(line_topo, line_book, line_feed):
    service = make_service(line_feed)
    s = trio.socket.socket()
    await s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    async with replay_running(service):
        async with trio.open_nursery() as outer:
            shell = None
            async with running(digest=line_topo.digest, n_cells=line_topo.n_cells, port=port) as server:
                shell = _shell(line_topo, line_book, server)
                client = StopMonitoringClient(url(service), mode="multiple", timeout=1.0)
                await outer.start(shell.run, shell.siri_poller(client))
                await _wait(lambda: len(shell.fleet.vehicles) >= 3 and shell.fleet.counters.publishes >= 3)
            await trio.sleep(0.5)  # the server is gone
            async with running(digest=line_topo.digest, n_cells=line_topo.n_cells, port=port) as server2:
                viewer = await _viewer(server2, line_topo)
                await _wait(lambda: shell.conn.connects >= 2, 30.0)
                upd, _ = await _updates(viewer, 1.5)
                assert len(upd) >= 3  # the whole fleet is back on the new server
            outer.cancel_scope.cancel()


async def test_gtfs_rt_proxy_positions_and_trip_updates(line_topo, line_book, line_feed):
    service = make_service(line_feed)
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server, replay_running(service):
        viewer = await _viewer(server, line_topo)
        shell = _shell(line_topo, line_book, server)
        poller = shell.gtfsrt_poller(url(service, "/gtfs-rt/vehicle-positions"), url(service, "/gtfs-rt/trip-updates"))
        async with trio.open_nursery() as n:
            await n.start(shell.run, poller)
            await _wait(lambda: len(shell.fleet.vehicles) >= 3 and shell.fleet.counters.fixes >= 3)
            assert any(v.positions for v in shell.fleet.vehicles.values())
            upd, _ = await _updates(viewer, 1.0)
            assert len(upd) >= 3
            for fault, kind in [("truncated", "malformed_protobuf"), ("garbage", "malformed_protobuf"),
                                ("http503", "http_5xx")]:
                good = shell.good_polls
                await _control(service, f"fault={fault}&count=1")
                await _wait(lambda kind=kind: shell.metrics.value("entitynet_proxy_errors_total", kind=kind) >= 1)
                await _wait(lambda good=good: shell.good_polls > good)
            assert shell.fleet.counters.retired_stale == 0
            n.cancel_scope.cancel()


async def test_single_mode_polls_complete_when_some_requests_fail(line_topo, line_book, line_feed):
    """`--mode single` (a request per stop): failing requests are counted by kind and the poll goes on with the
    other stops, so it completes and their vehicles are used."""
    service = make_service(line_feed)
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server, replay_running(service):
        shell = _shell(line_topo, line_book, server)
        client = StopMonitoringClient(url(service), mode="single", timeout=1.0)
        async with trio.open_nursery() as n:
            await n.start(shell.run, shell.siri_poller(client))
            await _wait(lambda: len(shell.fleet.vehicles) >= 3)
            good, calls = shell.good_polls, shell.metrics.value("entitynet_proxy_calls_total")
            await _control(service, "fault=http500&count=2")
            await _wait(lambda: shell.metrics.value("entitynet_proxy_request_errors_total", kind="http_5xx") == 2)
            await _wait(lambda: shell.good_polls > good + 1)
            assert shell.metrics.value("entitynet_proxy_errors_total", kind="http_5xx") == 0  # no poll failed
            assert shell.metrics.value("entitynet_proxy_calls_total") > calls
            assert len(shell.fleet.vehicles) >= 3
            # every request of a poll failing is still a failed poll, counted once
            await _control(service, f"fault=http500&count={len(line_book.stops)}")
            await _wait(lambda: shell.metrics.value("entitynet_proxy_errors_total", kind="http_5xx") == 1)
            n.cancel_scope.cancel()


async def test_an_unforeseen_error_in_a_poll_is_counted_and_survived(line_topo, line_book, line_feed):
    service = make_service(line_feed)
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server, replay_running(service):
        shell = _shell(line_topo, line_book, server)
        real = shell.siri_poller(StopMonitoringClient(url(service), mode="multiple", timeout=1.0))
        calls = []

        def flaky():
            calls.append(1)
            if len(calls) == 2:
                raise KeyError("something nobody foresaw")
            return real()

        async with trio.open_nursery() as n:
            await n.start(shell.run, flaky)
            await _wait(lambda: shell.metrics.value("entitynet_proxy_errors_total", kind="other") == 1)
            await _wait(lambda: shell.good_polls >= 2 and len(calls) >= 3)
            n.cancel_scope.cancel()


def test_a_refused_handshake_is_a_clean_command_error(line_topo, line_book):
    """A server that refuses the proxy (wrong topology digest) ends the command with a message, no traceback."""
    import argparse

    from entitynet.cli import CommandError
    from proxies import commands

    got: list[BaseException] = []

    def command(args) -> None:
        try:
            commands._run_shell(args, line_topo, line_book, lambda shell: lambda: [])
        except CommandError as exc:
            got.append(exc)

    async def serve_and_run():
        async with running(digest="another-map", n_cells=line_topo.n_cells) as server:
            args = argparse.Namespace(server=("127.0.0.1", server.port), token="", poll=0.5, timeout=1.0,
                                      stale_after=300.0, metrics_port=None, duration=5.0)
            await trio.to_thread.run_sync(command, args)

    trio.run(serve_and_run)
    assert got and "refused" in str(got[0]) and "digest" in str(got[0])


async def test_a_single_mode_poll_with_slow_stops_keeps_its_good_answers(line_topo, line_book, line_feed):
    """Answers that take time and stops that time out must not push a poll past the shell's limit: the poll
    stops sending at its budget and keeps the answers it got (it used to be dropped whole as too slow)."""
    service = make_service(line_feed, latency=0.6, slow_s=3.0)
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server, replay_running(service):
        cfg = ProxyConfig(("127.0.0.1", server.port), poll=30.0, tick=0.2, timeout=1.0, poll_grace=0.5)
        shell = ProxyShell(line_topo, line_book, cfg)
        assert len(line_book.stops) == 6
        await _control(service, "fault=none&count=4")  # four good answers of 0.6 s, then two stops time out
        await _control(service, "fault=slow&count=2")
        client = StopMonitoringClient(url(service), mode="single", timeout=1.0)
        async with trio.open_nursery() as n:
            await n.start(shell.run, shell.siri_poller(client))
            await _wait(lambda: shell.good_polls + shell.metrics.value("entitynet_proxy_errors_total",
                                                                       kind="timeout") > 0)
            assert shell.metrics.value("entitynet_proxy_errors_total", kind="timeout") == 0
            assert shell.good_polls == 1 and shell.metrics.value("entitynet_proxy_calls_total") > 0
            assert shell.metrics.value("entitynet_proxy_requests_not_sent_total") >= 1
            n.cancel_scope.cancel()


async def test_a_poll_abandoned_at_its_limit_holds_back_the_next_one(line_topo, line_book):
    """A poll thread given up on at the time limit still runs: the next poll waits for it to end rather than use
    the same client beside it."""
    async with running(digest=line_topo.digest, n_cells=line_topo.n_cells) as server:
        cfg = ProxyConfig(("127.0.0.1", server.port), poll=0.05, tick=0.2, timeout=0.1, poll_grace=0.0)
        shell = ProxyShell(line_topo, line_book, cfg)
        running_now, most = [0], [0]
        lock = threading.Lock()

        def poller():
            with lock:
                running_now[0] += 1
                most[0] = max(most[0], running_now[0])
            time.sleep(0.5)  # past the 0.3 s limit: abandoned
            with lock:
                running_now[0] -= 1
            return []

        async with trio.open_nursery() as n:
            await n.start(shell.run, poller)
            await _wait(lambda: shell.metrics.value("entitynet_proxy_errors_total", kind="timeout") >= 3)
            n.cancel_scope.cancel()
    assert most[0] == 1
