"""The trio client connection against a real in-process server: many entities, reconnect with replay,
clock offset from PING/PONG, queries, and a clear refusal on a topology mismatch."""

from __future__ import annotations

import time

import pytest
import trio

from entitynet import protocol as P
from entitynet.connection import Connection, HandshakeRefused, QueryRefused
from tests.entitynet.server_helpers import DIGEST, Raw, running


async def _wait(pred, timeout=5.0):
    with trio.fail_after(timeout):
        while not pred():
            await trio.sleep(0.005)


def _viewer(server, cells, seen):
    def on(m):
        if isinstance(m, P.Welcome):
            seen.clear()  # entity ids are per session
        elif isinstance(m, P.Update):
            seen[m.entity] = m
        elif isinstance(m, P.Leave):
            seen.pop(m.entity, None)

    return Connection(("127.0.0.1", server.port), DIGEST, on_message=on, backoff=(0.01, 0.05))


async def test_many_entities_reconnect_and_replay():
    async with running() as server, trio.open_nursery() as n:
        seen: dict[int, P.Update] = {}
        view = _viewer(server, (1, 2), seen)
        await view.subscribe((1, 2))
        await n.start(view.run)
        proxy = Connection(("127.0.0.1", server.port), DIGEST, backoff=(0.01, 0.05))
        await n.start(proxy.run)
        await proxy.publish(*[P.Publish(i, 1, (1 + i % 2,), 30_000, b"%d" % i) for i in range(50)])
        await _wait(lambda: len(seen) == 50)
        # the server drops both connections (as it drops one: its scope cancelled, then the stream closed;
        # closing a stream from outside would leave the read hub serving a stale descriptor): they come back,
        # re-subscribe and re-publish
        for conn in list(server.conns.values()):
            conn.scope.cancel()
        await _wait(lambda: proxy.connects == 2 and view.connects == 2)
        await _wait(lambda: len(seen) == 50 and len(server.sb.entities) == 50)
        assert sorted(u.payload for u in seen.values()) == sorted(b"%d" % i for i in range(50))
        # a state published while connected again flows as usual
        await proxy.publish(P.Publish(0, 2, (1,), 30_000, b"new"))
        await _wait(lambda: any(u.payload == b"new" for u in seen.values()))
        await view.set_subscription((2,))
        await _wait(lambda: len(seen) == 25)
        n.cancel_scope.cancel()


async def test_clock_offset_from_ping_pong():
    async with running(clock=lambda: time.time() + 1234.5) as server, trio.open_nursery() as n:
        c = Connection(("127.0.0.1", server.port), DIGEST, ping_interval=0.02)
        await n.start(c.run)
        await _wait(lambda: len(c.clock_estimate.samples) >= 3)
        assert c.clock_estimate.offset == pytest.approx(1234.5, abs=0.05)
        assert c.server_time() - time.time() == pytest.approx(1234.5, abs=0.05)
        n.cancel_scope.cancel()


async def test_query_and_rate_refusal():
    async with running(switch={"query_rate": 0.0, "query_burst": 1}) as server, trio.open_nursery() as n:
        c = Connection(("127.0.0.1", server.port), DIGEST)
        await n.start(c.run)
        await c.publish(P.Publish(1, 1, (4,), 10_000, b"x"))
        r = await c.query(P.QUERY_CELLS, (4,))
        assert [u.payload for u in r.entities] == [b"x"]
        with pytest.raises(QueryRefused):
            await c.query(P.QUERY_CELLS, (4,))
        n.cancel_scope.cancel()


async def test_topology_mismatch_is_a_clear_refusal():
    async with running() as server:
        c = Connection(("127.0.0.1", server.port), "another-digest")
        with pytest.raises(HandshakeRefused, match="digest"):
            await c.run()


async def test_websocket_transport():
    async with running(ws_port=0) as server, trio.open_nursery() as n:
        seen: dict[int, P.Update] = {}
        view = Connection(f"ws://127.0.0.1:{server.ws_port}/", DIGEST,
                          on_message=lambda m: isinstance(m, P.Update) and seen.__setitem__(m.entity, m))
        await view.subscribe((3,))
        await n.start(view.run)
        pub = Connection(f"ws://127.0.0.1:{server.ws_port}/", DIGEST)
        await n.start(pub.run)
        await pub.publish(P.Publish(1, 1, (3,), 10_000, b"ws"))
        await _wait(lambda: len(seen) == 1)
        n.cancel_scope.cancel()


async def test_redirect_moves_viewer_and_entities_to_the_named_shard():
    """Shard A (a scripted fake) welcomes us, then REDIRECTs to shard B (a real server): the connection dials
    B, re-sends its subscription and its entities' latest states there, and closes A."""
    listeners = await trio.open_tcp_listeners(0, host="127.0.0.1")
    a_port = listeners[0].socket.getsockname()[1]
    got_at_a: list[P.Message] = []
    a_closed = trio.Event()

    async with running() as b, trio.open_nursery() as n:
        async def shard_a(task_status=trio.TASK_STATUS_IGNORED):
            task_status.started()
            stream = await listeners[0].accept()
            raw = Raw(stream)
            hello = await raw.read()
            assert hello and isinstance(hello[0], P.Hello)
            await raw.send(P.Welcome(P.PROTOCOL_VERSION, 1, 0))
            with trio.fail_after(5):
                while not any(isinstance(m, P.Publish) for m in got_at_a):
                    got_at_a.extend(await raw.read() or [])
            await raw.send(P.Redirect(2, f"127.0.0.1:{b.port}"))
            while await raw.read() is not None:  # until the client closes A
                pass
            a_closed.set()

        await n.start(shard_a)
        seen: list[P.Message] = []
        c = Connection(("127.0.0.1", a_port), DIGEST, on_message=seen.append, backoff=(0.01, 0.05))
        await c.subscribe((7,))
        await c.publish(P.Publish(1, 1, (7,), 30_000, b"moved"))
        await n.start(c.run)
        watcher = await Raw.connect(b)
        await watcher.send(P.Subscribe((7,), ()))
        upd = await watcher.expect(P.Update)  # the entity reached B without being published again
        assert upd.payload == b"moved"
        await _wait(lambda: a_closed.is_set() and c.address == ("127.0.0.1", b.port) and c.connected.is_set())
        assert any(isinstance(m, P.Redirect) for m in seen)
        assert len(b.sb.entities) == 1
        await watcher.send(P.Publish(5, 1, (7,), 30_000, b"at-b"))  # our subscription moved to B as well
        await _wait(lambda: any(isinstance(m, P.Update) and m.payload == b"at-b" for m in seen))
        n.cancel_scope.cancel()
    await listeners[0].aclose()


async def test_a_decoder_shared_by_two_viewers_gets_every_frame():
    decoded: list[int] = []

    def decode(payload: bytes) -> list[P.Message]:  # any callable that returns what the codec returns
        msgs = P.decode_payload(payload)
        decoded.append(len(msgs))
        return msgs

    async with running() as server, trio.open_nursery() as n:
        seen: list[dict[int, P.Update]] = [{}, {}]
        views = []
        for i in range(2):
            v = Connection(("127.0.0.1", server.port), DIGEST, decode=decode,
                           on_message=lambda m, s=seen[i]: s.__setitem__(m.entity, m) if isinstance(m, P.Update)
                           else None)
            await v.subscribe((3,))
            await n.start(v.run)
            views.append(v)
        proxy = Connection(("127.0.0.1", server.port), DIGEST)
        await n.start(proxy.run)
        await proxy.publish(*[P.Publish(i, 1, (3,), 30_000, b"%d" % i) for i in range(5)])
        await _wait(lambda: all(len(s) == 5 for s in seen))
        assert sum(decoded) >= 10 + 2  # both viewers' UPDATEs and WELCOMEs went through it
        n.cancel_scope.cancel()
