"""The server's writing path over real loopback sockets (issue 9): viewers of many entities are not dropped,
and no frame exceeds the max_frame the server announces, whatever a viewer sees or asks."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from entitynet.connection import Connection
from tests.entitynet.server_helpers import DIGEST, Raw, running


async def _publish_many(server, n: int, cells: int, payload: bytes = b"s", per_frame: int = 2000) -> list[Raw]:
    """n entities spread over `cells` cells, by as many publishers as the per-client entity limit needs."""
    pubs: list[Raw] = []
    per_pub = server.sb.config.max_entities_per_client
    for first in range(0, n, per_pub):
        p = await Raw.connect(server)
        pubs.append(p)
        ids = range(first, min(n, first + per_pub))
        for i in range(0, len(ids), per_frame):
            await p.send(*[P.Publish(e, 1, (e % cells,), 60_000, payload) for e in ids[i : i + per_frame]])
        await p.send(P.Ping(1))
        await p.expect(P.Pong)  # all of this publisher's frames are processed
    return pubs


async def test_a_viewer_of_more_than_max_batch_entities_is_not_dropped(flush_path):
    async with running() as server:  # defaults: max_batch 20,000, max_pending 50,000, max_control 1,000
        n = server.config.max_batch + 1500
        pubs = await _publish_many(server, n, cells=100)
        view = await Raw.connect(server)
        await view.send(P.Subscribe(tuple(range(100)), ()))
        seen: set[int] = set()
        with trio.fail_after(30):
            while len(seen) < n:
                msgs = await view.read()
                assert msgs is not None, "the viewer was disconnected"
                for m in msgs:
                    assert not isinstance(m, P.Error), m
                    if isinstance(m, P.Update):
                        seen.add(m.entity)
        await view.send(P.Ping(2))
        await view.expect(P.Pong)
        assert server.sb.stats["slow_consumers"] == 0
        for p in pubs:
            await p.aclose()


async def _connection(server, got: list) -> Connection:
    return Connection(("127.0.0.1", server.port), DIGEST, on_message=got.append, backoff=(0.05, 0.2),
                      ping_interval=60.0)


async def test_every_frame_fits_max_frame_so_the_projects_connection_receives_everything(flush_path):
    """1,000 entities with 2 KiB payloads are a 2 MB snapshot: it must reach a Connection (default limits, which
    refuse any frame over 1 MiB with FRAME_TOO_LARGE) in several frames, on its first connection."""
    async with running() as server:
        big = b"x" * server.sb.config.codec.max_payload
        pubs = await _publish_many(server, 1000, cells=10, payload=big, per_frame=200)
        got: list[P.Message] = []
        conn = await _connection(server, got)
        async with trio.open_nursery() as n:
            await n.start(conn.run)
            await conn.set_subscription(range(10))
            with trio.fail_after(20):
                while len({m.entity for m in got if isinstance(m, P.Update)}) < 1000:
                    await trio.sleep(0.01)
            # and updates (not only the snapshot) are split as well: all 1,000 again in one burst
            for i in range(0, 1000, 200):
                await pubs[0].send(*[P.Publish(e, 2, (e % 10,), 60_000, big) for e in range(i, i + 200)])
            with trio.fail_after(20):
                while len({m.entity for m in got if isinstance(m, P.Update) and m.seq == 2}) < 1000:
                    await trio.sleep(0.01)
            # a query whose answer would be 2 MB comes as one result cut to fit one frame
            res = await conn.query(P.QUERY_CELLS, range(10), timeout=10)
            assert 0 < len(res.entities) < 1000 and all(u.payload == big for u in res.entities)
            assert conn.connects == 1
            assert not [m for m in got if isinstance(m, P.Error)]
            n.cancel_scope.cancel()


async def test_many_small_states_are_split_by_bytes_too(flush_path):
    """16,000 entities with 48-byte payloads: under max_batch messages, but over 1 MiB."""
    async with running() as server:
        pubs = await _publish_many(server, 16_000, cells=50, payload=b"y" * 48)  # kept open: entities stay
        got: list[P.Message] = []
        conn = await _connection(server, got)
        async with trio.open_nursery() as n:
            await n.start(conn.run)
            await conn.set_subscription(range(50))
            with trio.fail_after(30):
                while len({m.entity for m in got if isinstance(m, P.Update)}) < 16_000:
                    await trio.sleep(0.02)
            assert conn.connects == 1 and len(pubs) == 1
            n.cancel_scope.cancel()
