"""Publishers roaming with the border band, over a real nats-server: two in-process shards, a real client
`Connection` (its REDIRECTs followed for real), viewers on both shards that must never show the publisher twice
and must see every state it publishes while a neighbour serves it."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from tests.entitynet.server_helpers import Raw

from .shard_helpers import N_CELLS, shards, two_regions, until
from .test_shards import _view

LINE = [[c for c in (i - 1, i + 1) if 0 <= c < N_CELLS] for i in range(N_CELLS)]


async def _until_seq(w: Raw, seq: int, visible: dict[int, tuple], log: list) -> None:
    """Read `w` until it shows state `seq`, checking it never shows two ids of the one publisher at once."""
    with trio.fail_after(5):
        while True:
            batch, w.pending = w.pending, []
            if not batch:
                batch = await w.read()
            for m in batch:
                log.append(m)
                if isinstance(m, P.Update):
                    visible[m.entity] = m.cells
                elif isinstance(m, P.Leave):
                    visible.pop(m.entity, None)
                assert len(visible) <= 1, f"the publisher was shown twice: {log}"
            if any(isinstance(m, P.Update) and m.seq == seq for m in batch):
                return


async def test_a_publisher_dithering_on_a_border_stays_and_one_going_deep_moves_once(nats_server):
    from entitynet.connection import Connection
    from tests.entitynet.server_helpers import DIGEST

    async with shards(nats_server.urls, two_regions(), cluster_kw={"cell_adjacency": LINE}) as (a, b):
        watchers = [await _view(a, 49, 50, 52), await _view(b, 49, 50, 52)]
        for s in (a, b):
            await s.cluster.nc.flush()
        await trio.sleep(0.15)  # a heartbeat of each: addresses known (the first PUBLISH, at 49, is still
        # held until b is heard after the client came, since b could be serving a client failing over: a's ask
        # for b's heartbeat makes that a NATS round trip)
        redirects: list[P.Redirect] = []
        conn = Connection(("127.0.0.1", a.port), DIGEST, backoff=(0.01, 0.05),
                          on_message=lambda m: redirects.append(m) if isinstance(m, P.Redirect) else None)
        seen = [({}, []), ({}, [])]
        async with trio.open_nursery() as n:
            await n.start(conn.run)
            for seq in range(1, 9):  # across the border and back, four times: one cell into b's region at most
                cell = 49 if seq % 2 else 50
                await conn.publish(P.Publish(1, seq, (cell,), 10_000, b"x"))
                for w, (visible, log) in zip(watchers, seen, strict=True):
                    await _until_seq(w, seq, visible, log)
                    assert list(visible.values()) == [(cell,)]
            assert not redirects and a.sb.stats["redirects"] == 0
            await conn.publish(P.Publish(1, 9, (52,), 10_000, b"x"))  # two cells deep: beyond the band
            await until(lambda: redirects, timeout=5)
            assert redirects[0].shard == 1
            await until(lambda: any(e.owner.mirror is None for e in b.sb.entities.values()), timeout=5)
            await conn.publish(P.Publish(1, 10, (52,), 10_000, b"x"))
            for w, (visible, log) in zip(watchers, seen, strict=True):
                await _until_seq(w, 10, visible, log)
                assert list(visible.values()) == [(52,)]
            assert a.sb.stats["redirects"] == 1 and len(redirects) == 1
            n.cancel_scope.cancel()
