"""The read hub (entitynet.server.readhub): one task serves every plain-TCP connection from one epoll set, and
hands a connection to its own task when a frame must await. Over real loopback sockets: clients that speak at
once are served in one wake-up, a frame that yields between slices and the frames behind it keep their order,
a token lookup goes through the connection's task and back, and a connection that ends leaves the set."""

from __future__ import annotations

import os
import socket

import trio

from entitynet import protocol as P
from entitynet.server import reading
from entitynet.server.readhub import ReadHub
from tests.entitynet.server_helpers import Raw, flows, pair, running


async def test_clients_that_ping_at_once_are_served_in_one_wake_up():
    async with running(latency_budget=0.0) as server:
        clients = [await Raw.connect(server) for _ in range(20)]
        await trio.testing.wait_all_tasks_blocked()
        assert len(server.hub) == 20  # every connection waits in the hub, none in its own task
        passes = server.hub.passes
        ping = P.encode_frame([P.Ping(7)])
        for c in clients:  # synchronous sends: all twenty are queued before the server's loop runs again
            os.write(c.stream.socket.fileno(), ping)
        for c in clients:
            assert (await c.expect(P.Pong)).client_ms == 7
        assert server.hub.passes - passes <= 2  # one poll found them all (a second if the loop woke early)


async def test_a_frame_that_yields_between_slices_and_the_frames_behind_it_keep_their_order(monkeypatch):
    monkeypatch.setattr(reading, "FEED_YIELD_S", 0.0)  # every SUBSCRIBE slice hands the rest to the task
    async with running(latency_budget=0.0) as server:
        pub, view = await pair(server, cell=5)
        c = await Raw.connect(server)
        await trio.testing.wait_all_tasks_blocked()
        in_hub = len(server.hub)
        handed: list = []
        hand_off = server._hand_off
        server._hand_off = lambda conn, work: (handed.append(work), hand_off(conn, work))
        frames = (P.encode_frame([P.Subscribe((1,), ()), P.Ping(1), P.Subscribe((2,), ()), P.Ping(2)])
                  + P.encode_frame([P.Ping(3)]) + P.encode_frame([P.Subscribe((5,), (1,)), P.Ping(4)]))
        await c.send_bytes(frames)  # one write: the hub reads all three frames at once
        got = [(await c.expect(P.Pong)).client_ms for _ in range(4)]
        assert got == [1, 2, 3, 4]
        assert any(isinstance(w, tuple) and w[1] > 0 for w in handed)  # the task went on mid-frame
        await pub.send(P.Publish(1, 9, (5,), 10_000, b"z"))
        await c.expect(P.Update, pred=lambda u: u.seq == 9)  # its last SUBSCRIBE is in place
        await trio.testing.wait_all_tasks_blocked()
        assert len(server.hub) == in_hub  # handed back to the hub once caught up
        await flows(pub, view, 10, cell=5)


async def test_a_subscribe_and_its_barrier_ping_finish_in_the_hub_without_a_hand_over(monkeypatch):
    monkeypatch.setattr(reading, "FEED_YIELD_S", 0.0)  # every slice would yield, were the rest not one PING
    async with running(latency_budget=0.0) as server:
        pub, view = await pair(server, cell=5)
        c = await Raw.connect(server)
        await trio.testing.wait_all_tasks_blocked()
        handed: list = []
        hand_off = server._hand_off
        server._hand_off = lambda conn, work: (handed.append(work), hand_off(conn, work))
        await c.send_bytes(P.encode_frame([P.Subscribe((5,), ()), P.Ping(7)]))
        assert (await c.expect(P.Pong)).client_ms == 7
        assert handed == []  # answered in the same pass: no checkpoint, no task
        await c.send_bytes(P.encode_frame([P.Subscribe((6,), ()), P.Ping(8), P.Publish(1, 1, (6,), 1000, b"")]))
        assert (await c.expect(P.Pong)).client_ms == 8
        assert any(isinstance(w, tuple) and w[1] > 0 for w in handed)  # more than PINGs left: it yields


async def test_a_token_lookup_goes_through_the_connections_task_and_back(tmp_path):
    from entitynet.auth import TokenStore

    db = tmp_path / "users.sqlite"
    token = TokenStore(db).add_user("alice")
    async with running(open_mode=False, users_db=str(db)) as server:
        c = await Raw.connect(server, token=token)
        await trio.testing.wait_all_tasks_blocked()
        assert len(server.hub) == 1
        await c.send(P.Ping(5))
        assert (await c.expect(P.Pong)).client_ms == 5


async def test_a_connection_that_ends_leaves_the_set_and_its_descriptor_can_be_reused():
    async with running() as server:
        pub, view = await pair(server)
        for _ in range(3):
            c = await Raw.connect(server)
            await trio.testing.wait_all_tasks_blocked()
            assert len(server.hub) == 3
            c.stream.socket.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\0\0\0\0\0\0\0")
            await c.aclose()
            with trio.fail_after(5):
                while len(server.hub) != 2 or len(server.conns) != 2:
                    await trio.sleep(0.01)
        await flows(pub, view, 4)


async def test_the_hub_alone_serves_ready_descriptors_and_closes_its_set_when_cancelled():
    a, b = socket.socketpair()
    a.setblocking(False)
    seen = []

    class C:
        fd = a.fileno()

    hub = ReadHub(lambda conn: seen.append(os.read(conn.fd, 100)))
    conn = C()
    hub.add(conn)
    async with trio.open_nursery() as n:
        n.start_soon(hub.run)
        b.send(b"xy")
        with trio.fail_after(5):
            while not seen:
                await trio.sleep(0.001)
        hub.discard(conn)
        hub.discard(conn)  # twice: a no-op
        b.send(b"z")  # no longer in the set: not read
        await trio.sleep(0.05)
        n.cancel_scope.cancel()
    assert seen == [b"xy"] and len(hub) == 0
    assert a.recv(10) == b"z"
    a.close()
    b.close()


async def test_a_stopped_hub_takes_no_connection_and_lets_go_of_one_quietly():
    a, b = socket.socketpair()

    class C:
        fd = a.fileno()

    hub = ReadHub(lambda conn: None)
    conn = C()
    hub.add(conn)
    async with trio.open_nursery() as n:
        n.start_soon(hub.run)
        await trio.testing.wait_all_tasks_blocked()
        n.cancel_scope.cancel()  # the server stopping: the hub closes its set
    hub.discard(conn)  # a reader task's `finally` after the hub stopped
    hub.add(conn)  # one that was handing back
    assert len(hub) == 0
    a.close()
    b.close()
