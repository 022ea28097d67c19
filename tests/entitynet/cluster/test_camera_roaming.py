"""Viewers roam by their camera: real `entitynet serve --cluster` processes and nats-server on loopback; a viewer
whose camera walks across a region border (and dithers on it first) is REDIRECTed once, never shows an entity
twice, and never misses a visible one for longer than one validity period. Plus the CAMERA message itself."""

from __future__ import annotations

import pytest
import trio

from entitynet import protocol as P
from entitynet.cluster.local import LocalShards
from entitynet.cluster.natsd import NatsCluster
from tests.entitynet.cluster.shard_helpers import town_artifact
from topology.artifact import load
from topology.build import BuildConfig
from topology.pvs import PvsConfig
from topology.regions import build_regions

VALIDITY_MS = 3000


def test_camera_message_round_trip_and_bad_values():
    m = P.Camera(12.5, -300.25, 1.7)
    assert P.decode_payload(P.encode_payload([m])) == [m]
    for bad in ([P.CAMERA, float("nan"), 0.0, 0.0], [P.CAMERA, 1e9, 0.0, 0.0], [P.CAMERA, "1", 0.0, 0.0],
                [P.CAMERA, 1.0, 2.0]):
        import msgpack

        with pytest.raises(P.ProtocolError):
            P.decode_payload(msgpack.packb([bad]))


def test_a_session_sends_its_camera_only_where_welcome_announced_it():
    from entitynet.session import ClientSession
    from entitynet.session.events import Send

    def sent(actions) -> list:
        return [m for a in actions if isinstance(a, Send) for m in a.msgs]

    for limits, expect in (({}, False), ({"camera": 1}, True)):  # a single server (or an old one) never gets it
        s = ClientSession(("127.0.0.1", 1), "d")
        s.set_camera(1.0, 2.0, 3.0)
        s.subscribe((5,))
        (connect,) = [a for a in s.start(0.0)]
        s.connection_made(connect.link, 0.0)
        out = sent(s.receive(connect.link, [P.Welcome(1, 1, 0, limits)], 0.0))
        assert (P.Camera(1.0, 2.0, 3.0) in out) == expect
        if expect:  # the camera goes first, so the shard judges the viewer by its camera, not its cells
            assert out.index(P.Camera(1.0, 2.0, 3.0)) < [type(m) for m in out].index(P.Subscribe)
        assert (P.Camera(4.0, 5.0, 6.0) in sent(s.set_camera(4.0, 5.0, 6.0))) == expect


async def test_only_a_shard_announces_camera_and_a_single_server_ignores_it(nats_server):
    """One server's WELCOME is unchanged (no `camera`: clients never send it there), and a CAMERA that reaches
    it anyway is accepted and does nothing; a shard's WELCOME announces it."""
    from tests.entitynet.server_helpers import Raw, running

    from .shard_helpers import shards, two_regions

    async with running() as server:
        c = Raw(await trio.open_tcp_stream("127.0.0.1", server.port))
        await c.send(P.Hello(P.PROTOCOL_VERSION, "", server.sb.config.digest))
        w = await c.expect(P.Welcome)
        assert "camera" not in w.limits
        await c.send(P.Camera(1.0, 2.0, 3.0), P.Ping(7))
        await c.expect(P.Pong)
        assert not [m for m in c.pending if isinstance(m, P.Error)]
    async with shards(nats_server.urls, two_regions()) as (a, _b):
        c = Raw(await trio.open_tcp_stream("127.0.0.1", a.port))
        await c.send(P.Hello(P.PROTOCOL_VERSION, "", a.sb.config.digest))
        w = await c.expect(P.Welcome)
        assert w.limits.get("camera") == 1


def _camera_bus():
    """Two shards in miniature (test_core.Bus) whose regions split the plane at x = 0, viewers roaming."""
    from .test_core import Bus

    bus = Bus(2, redirect_viewers=True)
    bus.regions.region_at = lambda x, y: 0 if x < 0 else 1  # (the test map has no view grid)
    bus.run(0.0)
    bus.run(0.5)  # heartbeats heard: addresses known
    return bus


def _redirects(sb, cid) -> list[int]:
    from tests.entitynet.switchboard_helpers import of, recv

    return [r.shard for r in of(recv(sb, cid), P.Redirect)]


def test_a_camera_at_rest_in_a_quiet_shards_region_is_redirected_once_that_shard_is_heard_again():
    """The REDIRECT cannot go while its target is quiet; the camera sends nothing more, and is still moved
    at the next heartbeat after the target is heard (the CI flake of the test below, in miniature)."""
    from tests.entitynet.switchboard_helpers import join

    bus = _camera_bus()
    a = bus.sbs[0]
    v = join(a, now=0.5)
    a.receive(v, [P.Subscribe((1, 60), ())], 0.5)
    bus.down = {1}
    bus.run(1.0)
    bus.run(1.7)  # shard 1 unheard for over quiet_s (1 s): going quiet, no REDIRECT goes to it
    a.receive(v, [P.Camera(100.0, 0.0, 1.7)], 1.7)
    bus.run(1.7)
    assert _redirects(a, v) == [] and v in bus.cores[0].camera_retry
    bus.down = set()
    for t in (1.8, 2.2, 2.7):
        bus.run(t)
    assert _redirects(a, v) == [1]
    assert v not in bus.cores[0].camera_retry
    bus.run(3.5)
    assert _redirects(a, v) == []  # once


def test_a_camera_in_a_dead_shards_region_stays_and_moves_when_that_shard_comes_back():
    from tests.entitynet.switchboard_helpers import join

    bus = _camera_bus()
    a = bus.sbs[0]
    bus.down = {1}
    for t in (1.0, 2.0, 3.0):
        bus.run(t)  # shard 1 declared dead: its region is ours now
    v = join(a, now=3.0)
    a.receive(v, [P.Subscribe((60,), ()), P.Camera(100.0, 0.0, 1.7)], 3.0)
    bus.run(3.0)
    assert _redirects(a, v) == []  # its region is served here meanwhile
    bus.down = set()
    for t in (3.5, 4.0, 4.5, 5.0, 5.5):
        bus.run(t)
    assert _redirects(a, v) == [1]


def test_a_camera_in_our_own_region_is_not_judged_again_and_a_gone_viewer_is_forgotten():
    from tests.entitynet.switchboard_helpers import join

    bus = _camera_bus()
    a = bus.sbs[0]
    core = bus.cores[0]
    home = join(a, now=0.5)
    a.receive(home, [P.Subscribe((1,), ()), P.Camera(-100.0, 0.0, 1.7)], 0.5)
    bus.down = {1}
    bus.run(1.7)
    away = join(a, now=1.7)
    a.receive(away, [P.Subscribe((1,), ()), P.Camera(100.0, 0.0, 1.7)], 1.7)
    assert core.camera_retry == {away}
    a.disconnect(away, 1.8)
    for t in (2.5, 3.1):
        bus.run(t)  # (at 2.5 shard 1 is declared dead, which sends our heartbeat early: judged at the next)
    assert core.camera_retry == set()


@pytest.fixture(scope="module")
def town_pvs(tmp_path_factory):
    pvs = PvsConfig(max_height=20.0, view_distance=300.0, workers=1)  # a view grid, built in a few seconds
    return town_artifact(tmp_path_factory, "camera", 5, BuildConfig(pvs=pvs))


def _border_on_line(regions, a, b) -> float:
    """The fraction along a -> b where the region changes (bisection on `region_at`)."""
    lo, hi = 0.0, 1.0
    r0 = regions.region_at(*a)
    for _ in range(30):
        mid = (lo + hi) / 2
        if regions.region_at(a[0] + mid * (b[0] - a[0]), a[1] + mid * (b[1] - a[1])) == r0:
            lo = mid
        else:
            hi = mid
    return lo


async def test_a_viewer_walking_its_camera_across_a_border_is_redirected_once(town_pvs, tmp_path):
    from entitynet.connection import Connection

    topo = load(town_pvs)
    regions = build_regions(topo, 2)
    map_path = tmp_path / "regions.json"
    regions.save(map_path)
    a, b = (-150.0, -150.0), (150.0, 150.0)
    assert (regions.region_at(*a), regions.region_at(*b)) == (0, 1)
    with NatsCluster(1, log_dir=tmp_path) as nats:
        # (the default dead-shard time, 2 s, not 1 s: nothing here kills a shard, and with 1 s a shard whose
        # heartbeats ran 1 s late on a loaded machine would be declared dead and its region passed on under the
        # test. A guess at the one timeout seen, under a helper's load in round 9; not reproduced with three busy
        # loops beside the test, before or after)
        shards = LocalShards(town_pvs, map_path, nats.urls, 2, tmp_path).start()
        try:
            addrs = [("127.0.0.1", p) for p in shards.ports]
            async with trio.open_nursery() as nursery:
                # three entities in each region, each published to its region's shard, renewed every second
                cells = {r: [int(c) for c in regions.cells_of(r)[::12][:3]] for r in (0, 1)}
                pubs = [Connection(addrs[r], topo.digest, backoff=(0.05, 0.2)) for r in (0, 1)]
                for c in pubs:
                    await nursery.start(c.run)

                async def keep_publishing() -> None:
                    seq = 0
                    while True:
                        seq += 1
                        for r in (0, 1):
                            await pubs[r].publish(*[P.Publish(i + 1, seq, (cell,), VALIDITY_MS, b"e%d-%d" % (r, i))
                                                    for i, cell in enumerate(cells[r])])
                        await trio.sleep(1.0)

                nursery.start_soon(keep_publishing)
                # the viewer sees every cell, so every entity is visible all the time wherever its camera is
                ghosts: dict[int, bytes] = {}  # eid -> the entity it shows (its payload)
                hidden_since: dict[bytes, float] = {}
                longest_gap = [0.0]
                redirects: list[P.Redirect] = []
                names = {b"e%d-%d" % (r, i) for r in (0, 1) for i in range(3)}

                def shown() -> dict[bytes, int]:
                    counts: dict[bytes, int] = {}
                    for p in ghosts.values():
                        counts[p] = counts.get(p, 0) + 1
                    return counts

                def account() -> None:
                    now = trio.current_time()
                    counts = shown()
                    assert all(n == 1 for n in counts.values()), f"an entity shown twice: {ghosts}"
                    for name in names:
                        if name in counts:
                            t0 = hidden_since.pop(name, None)
                            if t0 is not None:
                                longest_gap[0] = max(longest_gap[0], now - t0)
                        else:
                            hidden_since.setdefault(name, now)

                def on_message(m: P.Message) -> None:
                    if isinstance(m, P.Update):
                        ghosts[m.entity] = m.payload
                    elif isinstance(m, P.Leave):
                        ghosts.pop(m.entity, None)
                    elif isinstance(m, P.Welcome):
                        ghosts.clear()  # a viewer forgets its ghosts with its session (ids are per server)
                    elif isinstance(m, P.Redirect):
                        redirects.append(m)
                    account()

                viewer = Connection(addrs[0], topo.digest, backoff=(0.05, 0.2), on_message=on_message)
                viewer.session.set_camera(*a, 1.7)
                viewer.session.subscribe(tuple(range(int(topo.n_cells))))
                await nursery.start(viewer.run)
                with trio.fail_after(45):  # (a condition, not a duration: generous for a loaded CI machine)
                    while len(shown()) < len(names):
                        await trio.sleep(0.05)
                hidden_since.clear()
                longest_gap[0] = 0.0
                # walk to the border, dither across it for a while (+-6 m), then walk on into region 1
                f = _border_on_line(regions, a, b)
                at = lambda t: (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), 1.7)  # noqa: E731
                step = 6.0 / 424.0  # 6 m along the 424 m diagonal
                path = [i * step for i in range(int(f / step))]
                path += [f + (1 if i % 2 else -1) * 6.0 / 424.0 for i in range(30)]
                path += [f + i * step for i in range(int((1 - f) / step))]
                for t in path:
                    await viewer.camera(*at(t))
                    await trio.sleep(0.02)
                with trio.fail_after(30):  # (~1 s on a quiet machine: a deadline for a hang, not a measure)
                    while not redirects or len(shown()) < len(names):
                        await trio.sleep(0.05)
                await trio.sleep(1.0)  # anything late (a second REDIRECT, a LEAVE) would arrive by now
                account()
                assert [r.shard for r in redirects] == [1], redirects  # once, and to the camera's shard
                assert viewer.session.home == addrs[1]
                assert len(shown()) == len(names)
                assert longest_gap[0] < VALIDITY_MS / 1000, f"an entity was missing for {longest_gap[0]:.2f} s"
                nursery.cancel_scope.cancel()
        finally:
            shards.stop()
