"""Bad input over real loopback sockets: each offender gets its clear error or is closed, others keep going."""

from __future__ import annotations

import socket
import struct

import msgpack
import trio

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from tests.entitynet.server_helpers import Raw, flows, pair, running


async def _closed_with(server, data: bytes, code: ErrorCode, hello: bool = True) -> None:
    pub, view = await pair(server)
    await flows(pub, view, 1)
    bad = await Raw.connect(server, hello=hello)
    await bad.send_bytes(data)
    got = await bad.expect_closed()
    assert [m.code for m in got if isinstance(m, P.Error)] == [code], got
    await flows(pub, view, 2)


async def test_garbage_bytes():
    async with running() as server:
        await _closed_with(server, struct.pack(">I", 5) + b"\xc1\xc1\xc1\xc1\xc1", ErrorCode.MALFORMED)
        await _closed_with(server, P.frame(b"\x93\x01\x02"), ErrorCode.MALFORMED)  # truncated msgpack


async def test_four_gigabyte_length_prefix():
    async with running() as server:
        await _closed_with(server, b"\xff\xff\xff\xff" + b"x" * 100, ErrorCode.FRAME_TOO_LARGE)
        assert server.sb.errors[ErrorCode.FRAME_TOO_LARGE] == 1


async def test_unknown_type_and_handshake_required():
    async with running() as server:
        await _closed_with(server, P.frame(msgpack.packb([[77, 1]])), ErrorCode.UNKNOWN_TYPE)
        await _closed_with(server, P.encode_frame([P.Ping(1)]), ErrorCode.HANDSHAKE_REQUIRED, hello=False)


async def test_truncated_frame_then_vanish_mid_frame():
    async with running() as server:
        pub, view = await pair(server)
        other = await Raw.connect(server)
        await other.send(P.Publish(9, 1, (1,), 60_000, b"x"))
        u = await view.expect(P.Update)
        frame = P.encode_frame([P.Publish(9, 2, (1,), 60_000, b"y" * 100)])
        await other.send_bytes(frame[: len(frame) // 2])
        await flows(pub, view, 1)  # the half frame holds up nobody
        await other.aclose()  # vanishes mid-frame: its entity leaves, the half frame is discarded
        assert (await view.expect(P.Leave)).entity == u.entity
        await flows(pub, view, 2)
        with trio.fail_after(2):
            while len(server.conns) != 2:
                await trio.sleep(0.01)


async def test_publish_for_another_clients_entity():
    async with running() as server:
        pub, view = await pair(server)
        await flows(pub, view, 1)
        eid = next(iter(server.sb.entities))
        thief = await Raw.connect(server)
        await thief.send(P.Publish(eid, 99, (1,), 10_000, b"evil"), P.Unpublish(eid))
        assert (await thief.expect(P.Error)).code == ErrorCode.NOT_OWNER
        assert (await thief.expect(P.Error)).code == ErrorCode.NOT_OWNER
        await thief.send(P.Ping(3))
        await thief.expect(P.Pong)  # not fatal
        assert server.sb.entities[eid].payload == b"1"
        await flows(pub, view, 2)


async def test_nonexistent_cells():
    async with running(n_cells=50) as server:
        pub, view = await pair(server)
        c = await Raw.connect(server)
        await c.send(P.Subscribe((3, 50), ()), P.Publish(1, 1, (60,), 1000, b""))
        codes = [(await c.expect(P.Error)).code for _ in range(2)]
        assert codes == [ErrorCode.NO_SUCH_CELL] * 2
        assert server.sb.clients[max(server.sb.clients)].subs == set()
        await flows(pub, view, 1)


async def test_subscription_follow_and_query_floods():
    async with running(switch={"max_subscriptions": 20, "max_follows": 3, "query_rate": 1.0,
                               "query_burst": 2}) as server:
        pub, view = await pair(server)
        await pub.send(*[P.Publish(i, 1, (i % 50,), 60_000, b"") for i in range(10)], P.Ping(1))
        await pub.expect(P.Pong)
        eids = list(server.sb.entities)
        assert len(eids) == 10
        flood = await Raw.connect(server)
        await flood.send(*[P.Subscribe((i,), ()) for i in range(40)])
        await flood.send(*[P.Follow(e) for e in eids])
        await flood.send(*[P.Query(i, P.QUERY_CELLS, (1,)) for i in range(50)])
        await flood.send(P.Ping(1))
        await flood.expect(P.Pong)
        errs = [m.code for m in flood.pending if isinstance(m, P.Error)]
        assert errs.count(ErrorCode.LIMIT_SUBSCRIPTIONS) == 20
        assert errs.count(ErrorCode.LIMIT_FOLLOWS) == 7
        assert errs.count(ErrorCode.QUERY_RATE) == 48
        assert len([m for m in flood.pending if isinstance(m, P.QueryResult)]) == 2
        assert len(server.sb.clients[max(server.sb.clients)].subs) == 20
        await flows(pub, view, 2)


async def test_client_that_never_reads_is_dropped_and_others_keep_receiving():
    async with running(stall_timeout=0.3, switch={"max_pending": 100_000}) as server:
        pub, view = await pair(server)
        sock = trio.socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        await sock.connect(("127.0.0.1", server.port))
        lazy = Raw(trio.SocketStream(sock))
        await lazy.send(P.Hello(1, "", "test-digest"), P.Subscribe((1,), ()))
        with trio.fail_after(5):
            while len(server.sb.subscribers.get(1, ())) < 2:
                await trio.sleep(0.005)
        big = b"z" * 2000
        seq = 1
        with trio.fail_after(20):
            while len(server.conns) > 2:
                seq += 1
                await pub.send(*[P.Publish(100 + i, seq, (1,), 60_000, big + bytes([seq % 256]))
                                 for i in range(200)])
                await view.expect(P.Update, pred=lambda u, s=seq: u.seq == s)
                # coalescing keeps the lazy client's queue at one state per entity
                ob = next((server.sb.outbox(c) for c in server.conns if server.sb.outbox(c)), None)
                assert ob is None or ob.n_states <= 202
                await trio.sleep(0.01)
        assert server.sb.stats["slow_consumers"] == 1, (dict(server.sb.errors), dict(server.sb.stats))
        await flows(pub, view, 10_000)


async def test_slow_consumer_over_queue_bound_is_told():
    async with running(switch={"max_pending": 5}) as server:
        pub, view = await pair(server, cell=2)
        lazy = await Raw.connect(server)
        await lazy.send(P.Subscribe((1,), ()))
        await lazy.send(P.Ping(1))
        await lazy.expect(P.Pong)
        # 10 distinct entities in one frame: more than 5 pending states for `lazy` at the next flush
        await pub.send(*[P.Publish(i, 1, (1,), 60_000, b"") for i in range(10)])
        got = await lazy.expect_closed()
        assert [m.code for m in got if isinstance(m, P.Error)] == [ErrorCode.SLOW_CONSUMER]
        await flows(pub, view, 2, cell=2)


async def test_silent_connection_is_closed_after_handshake_timeout():
    async with running(handshake_timeout=0.3) as server:
        pub, view = await pair(server)
        silent = await Raw.connect(server, hello=False)
        got = await silent.expect_closed()
        assert [m.code for m in got] == [ErrorCode.HANDSHAKE_REQUIRED]
        await flows(pub, view, 1)


async def test_connections_beyond_the_limit_are_refused():
    async with running(max_clients=2) as server:
        pub, view = await pair(server)
        extra = await Raw.connect(server, hello=False)
        got = await extra.expect_closed()
        assert [m.code for m in got] == [ErrorCode.SERVER_FULL]
        await flows(pub, view, 1)


async def test_websocket_garbage_and_text_messages_are_refused():
    import trio_websocket

    async with running(ws_port=0) as server:
        pub, view = await pair(server)
        for bad, code in ((b"\xc1garbage", ErrorCode.MALFORMED), ("text", ErrorCode.MALFORMED)):
            async with trio_websocket.open_websocket_url(f"ws://127.0.0.1:{server.ws_port}/") as ws:
                await ws.send_message(bad)
                got = P.decode_payload(await ws.get_message())
                assert [m.code for m in got] == [code]
                with trio.fail_after(5):
                    try:
                        await ws.get_message()
                        raise AssertionError("the connection should be closed")
                    except trio_websocket.ConnectionClosed:
                        pass
        await flows(pub, view, 1)
