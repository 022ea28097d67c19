"""The plain-TCP reader (the read hub's `hubpass.hub_ready`, and `Server._read_plain`) and the PINGs it answers
itself (`Server._pong_now`), over real loopback sockets: a lock step's PING gets its PONG with nothing left for
the flusher, a PING behind pending states comes with them, bytes in any split still make frames, and a peer that
resets or vanishes mid-frame costs only its own connection."""

from __future__ import annotations

import socket
import struct

import trio

from entitynet import protocol as P
from tests.entitynet.server_helpers import Raw, flows, pair, running


async def test_a_lone_ping_is_answered_and_leaves_no_news_for_the_flusher():
    async with running(latency_budget=0.0) as server:
        c = await Raw.connect(server)
        await trio.testing.wait_all_tasks_blocked()
        frames = server.frames
        for k in range(1, 21):
            await c.send(P.Ping(k))
            pong = await c.expect(P.Pong)
            assert pong.client_ms == k
            assert not server.sb.has_news()  # written by the reader: nothing for the flusher to find
        assert server.frames - frames == 20  # one frame per PONG


async def test_a_ping_behind_pending_states_comes_in_one_frame_with_them():
    # a long flush interval and budget: the UPDATE waits in the viewer's outbox until the PING's frame
    async with running(flush_interval=30.0, flush_min_interval=30.0, latency_budget=30.0) as server:
        pub, view = await pair(server, cell=2)
        await trio.testing.wait_all_tasks_blocked()
        await pub.send(P.Publish(1, 5, (2,), 10_000, b"x"))
        await pub.send(P.Ping(1))
        await pub.expect(P.Pong)
        await view.send(P.Ping(9))
        msgs = await view.read()
        assert [type(m) for m in msgs] == [P.Pong, P.Update]


def _count_receive(server) -> list[int]:
    """Client ids of every frame the core's `receive` is fed from now on (the quick PONG path feeds none)."""
    fed: list[int] = []
    receive = server.sb.receive

    def counted(cid, *a, **kw):
        fed.append(cid)
        return receive(cid, *a, **kw)

    server.sb.receive = counted
    return fed


async def test_a_lone_ping_behind_pending_states_takes_them_past_the_core_in_one_write():
    async with running(flush_interval=30.0, flush_min_interval=30.0, latency_budget=30.0) as server:
        pub, view = await pair(server, cell=2)
        for e in (1, 2):
            await pub.send(P.Publish(e, 5, (2,), 10_000, b"x"))
        await pub.send(P.Ping(1))
        await pub.expect(P.Pong)
        await trio.testing.wait_all_tasks_blocked()
        fed, frames = _count_receive(server), server.frames
        await view.send(P.Ping(9))
        msgs = await view.read()
        assert [type(m) for m in msgs] == [P.Pong, P.Update, P.Update] and msgs[0].client_ms == 9
        assert fed == [] and server.frames - frames == 1  # answered from its bytes: one frame, one write
        assert not server.sb.has_news()  # taken and written: nothing left for the flusher


async def test_a_ping_behind_more_states_than_one_quick_frame_takes_the_usual_path_in_order():
    async with running(flush_interval=30.0, flush_min_interval=30.0, latency_budget=30.0) as server:
        pub, view = await pair(server, cell=2)
        server._fast_batch = 3  # the quick frame holds the PONG and at most 2 states
        for e in (1, 2, 3):
            await pub.send(P.Publish(e, 5, (2,), 10_000, b"x"))
        await pub.send(P.Ping(1))
        await pub.expect(P.Pong)
        await trio.testing.wait_all_tasks_blocked()
        fed = _count_receive(server)
        await view.send(P.Ping(9))
        got = []
        while len(got) < 4:
            got += await view.read()
        assert [type(m) for m in got] == [P.Pong, P.Update, P.Update, P.Update]
        assert len(fed) == 1  # fed to the core as usual; nothing was taken on the way


async def test_frames_split_into_single_bytes_and_many_frames_per_read_both_work():
    async with running() as server:
        pub, view = await pair(server, cell=3)
        data = P.encode_frame([P.Ping(1)]) + P.encode_frame([P.Publish(1, 2, (3,), 10_000, b"y"), P.Ping(2)])
        for b in data:
            await pub.send_bytes(bytes([b]))
        assert (await pub.expect(P.Pong)).client_ms == 1
        assert (await pub.expect(P.Pong)).client_ms == 2
        await view.expect(P.Update, pred=lambda u: u.seq == 2)
        await pub.send_bytes(P.encode_frame([P.Ping(3)]) * 50)  # fifty frames in one write
        for _ in range(50):
            assert (await pub.expect(P.Pong)).client_ms == 3


async def test_a_reset_peer_and_one_gone_mid_frame_cost_only_their_connections():
    async with running() as server:
        pub, view = await pair(server)
        for how in ("reset", "mid-frame"):
            raw = await Raw.connect(server)
            before = len(server.conns)
            sock = raw.stream.socket
            if how == "reset":
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # close sends RST
            else:
                await raw.send_bytes(P.encode_frame([P.Ping(1)])[:3])
            await raw.aclose()
            with trio.fail_after(5):
                while len(server.conns) >= before:
                    await trio.sleep(0.01)
        await flows(pub, view, 7)


async def test_a_malformed_frame_on_the_reader_gets_its_error_and_the_close():
    async with running() as server:
        pub, view = await pair(server)
        bad = await Raw.connect(server)
        await bad.send_bytes(struct.pack(">I", 3) + b"\xc1\xc1\xc1")  # 0xc1: never used in msgpack
        got = await bad.expect_closed()
        assert any(isinstance(m, P.Error) and m.code == P.ErrorCode.MALFORMED for m in got), got
        await flows(pub, view, 3)
