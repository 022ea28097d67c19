"""The stall timer counts only what the client fails to read, not the server's own freezes (issue 9, item 4)."""

from __future__ import annotations

import socket
import time

import trio

from entitynet import protocol as P
from entitynet.server.app import STALL_TICK_S
from entitynet.server.stall import StallClock
from tests.entitynet.server_helpers import DIGEST, Raw, running


def test_stall_clock_credits_late_ticks_only_up_to_the_cap():
    clock = StallClock(max_credit=0.25)
    assert clock.tick(100.0) == 0.0  # first tick: nothing to credit yet
    assert abs(clock.tick(100.1) - 0.1) < 1e-9
    assert clock.tick(107.1) == 0.25  # a 7 s freeze of the loop counts 0.25 s
    assert clock.tick(107.0) == 0.0  # time going back credits nothing
    stalled = sum(clock.tick(107.0 + 0.1 * k) for k in range(1, 51))  # 5 s of regular ticks count fully
    assert abs(stalled - 5.0) < 1e-6


async def test_a_server_freeze_does_not_drop_a_viewer_that_reads_promptly():
    async with running(stall_timeout=1.0) as server:
        pub = await Raw.connect(server)
        big = b"z" * 2000
        await pub.send(*[P.Publish(i, 1, (1,), 60_000, big) for i in range(400)])
        await pub.send(P.Ping(1))
        await pub.expect(P.Pong)
        # a viewer with a small receive buffer that has not read its 800 KB snapshot yet: the write blocks
        sock = trio.socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        await sock.connect(("127.0.0.1", server.port))
        view = Raw(trio.SocketStream(sock))
        await view.send(P.Hello(P.PROTOCOL_VERSION, "", DIGEST), P.Subscribe((1,), ()))
        with trio.fail_after(5):
            while not any(c.busy for c in server.conns.values()):
                await trio.sleep(0.005)
        time.sleep(3.0)  # the whole loop freezes (server included), as while one huge frame is processed
        seen: set[int] = set()
        with trio.fail_after(10):  # from now on the viewer reads promptly
            while len(seen) < 400:
                msgs = await view.read()
                assert msgs is not None, "the viewer was dropped"
                assert not [m for m in msgs if isinstance(m, P.Error)], msgs
                seen.update(m.entity for m in msgs if isinstance(m, P.Update))
        await view.send(P.Ping(2))
        await view.expect(P.Pong)
        assert server.sb.stats["slow_consumers"] == 0


async def test_a_viewer_that_stops_reading_is_still_dropped(flush_path):
    async with running(stall_timeout=0.5) as server:
        pub = await Raw.connect(server)
        big = b"z" * 2000
        await pub.send(*[P.Publish(i, 1, (1,), 60_000, big) for i in range(400)])
        sock = trio.socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        await sock.connect(("127.0.0.1", server.port))
        lazy = Raw(trio.SocketStream(sock))
        await lazy.send(P.Hello(P.PROTOCOL_VERSION, "", DIGEST), P.Subscribe((1,), ()))
        with trio.fail_after(10):
            while server.sb.stats["slow_consumers"] == 0:
                await trio.sleep(0.02)
            # the drop is counted when the writer is cancelled; the handler disconnects it a moment later
            while len(server.conns) != 1:
                await trio.sleep(0.02)
        assert len(server.conns) == 1 and server.sb.stats["slow_consumers"] == 1


async def test_an_idle_server_ticks_once_a_second_not_ten_times(flush_path, monkeypatch):
    """Housekeeping ticks every 0.1 s only while a write is blocked (stall accounting needs it); an idle server
    (or an idle shard) wakes for it about once a second, since ten wake-ups a second were most of its CPU."""
    from entitynet.server.app import Server

    ticks = []
    real = Server._check_stalls

    def counted(self):
        ticks.append(trio.current_time())
        return real(self)

    monkeypatch.setattr(Server, "_check_stalls", counted)
    async with running() as server:
        c = await Raw.connect(server)
        await trio.sleep(2.5)
        assert 1 <= len(ticks) <= 4, ticks  # 2-3 at 1 s; the old 0.1 s tick made about 25
        await c.aclose()


async def test_a_write_that_blocks_after_an_idle_spell_is_still_timed_from_its_start(flush_path):
    """After a long idle tick, a write that blocks brings the next tick to 0.1 s and starts its stall credit
    there: the viewer is dropped after about `stall_timeout`, not after the idle second too, nor before."""
    async with running(stall_timeout=0.5) as server:
        pub = await Raw.connect(server)
        await trio.sleep(1.2)  # housekeeping is in its idle tick
        sock = trio.socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        await sock.connect(("127.0.0.1", server.port))
        lazy = Raw(trio.SocketStream(sock))
        await lazy.send(P.Hello(P.PROTOCOL_VERSION, "", DIGEST), P.Subscribe((1,), ()))
        big = b"z" * 2000
        t0 = trio.current_time()
        await pub.send(*[P.Publish(i, 1, (1,), 60_000, big) for i in range(400)])
        with trio.fail_after(10):
            while not any(c.writing for c in server.conns.values()) and not server.sb.stats["slow_consumers"]:
                await trio.sleep(0.005)
        scope = server._tick_scope  # the write blocked: housekeeping's next tick is now at most 0.1 s away
        assert scope is None or scope.deadline <= trio.current_time() + STALL_TICK_S
        with trio.fail_after(10):
            while server.sb.stats["slow_consumers"] == 0:
                await trio.sleep(0.02)
        assert trio.current_time() - t0 >= 0.5  # never before its own stall_timeout
        await pub.aclose()
