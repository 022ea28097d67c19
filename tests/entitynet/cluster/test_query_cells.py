"""QUERY by cells across shards (real nats-server on loopback, in-process shard servers): the owners of a cell's
occupants answer, the privacy rule holds, each entity is in the result once, and a live shard that does not
answer costs `query_wait_s` and leaves out only its own entities."""

from __future__ import annotations

from entitynet import protocol as P
from tests.entitynet.server_helpers import Raw

from .shard_helpers import shards, two_regions, until


async def _publish_seen(server, pub: Raw, *msgs: P.Message) -> int:
    """Publish on `server` and wait until its own tables hold the entity; its server id."""
    await pub.send(*msgs)
    await until(lambda: any(e.owner.mirror is None for e in server.sb.entities.values()))
    return next(eid for eid, e in server.sb.entities.items() if e.owner.mirror is None)


async def test_query_by_cells_answers_from_the_owners_on_other_shards_with_the_privacy_rule(nats_server):
    async with shards(nats_server.urls, two_regions()) as (a, b):
        alice = await Raw.connect(a)
        eid = await _publish_seen(a, alice, P.Privacy("alice", ("bob",)), P.Publish(1, 1, (10,), 10_000, b"a1"))
        bob = await Raw.connect(b, token="bob")
        await bob.send(P.Privacy("bob", None))
        carol = await Raw.connect(b, token="carol")
        await carol.send(P.Privacy("carol", None))
        assert eid not in b.sb.entities  # nobody on b looks at cell 10: b holds no mirror of it
        await bob.send(P.Query(1, P.QUERY_CELLS, (10, 11, 60)))
        r = await bob.expect(P.QueryResult)
        assert [(u.entity, u.payload, u.identity) for u in r.entities] == [(eid, b"a1", "alice")]
        assert b.cluster.core.stats["queries_partial"] == 0  # every live shard answered (no timeout)
        await carol.send(P.Query(2, P.QUERY_CELLS, (10,)))
        r2 = await carol.expect(P.QueryResult)
        assert [(u.entity, u.identity) for u in r2.entities] == [(eid, None)]  # not in alice's audience
        # a viewer on b now mirrors the entity: the query still returns it once (the owner's answer wins)
        v = await Raw.connect(b)
        await v.send(P.Subscribe((10,), ()))
        await v.expect(P.Update)
        assert eid in b.sb.entities
        await bob.send(P.Query(3, P.QUERY_CELLS, (10,)))
        r3 = await bob.expect(P.QueryResult)
        assert [u.entity for u in r3.entities] == [eid]
        # entities on both shards, queried from either side
        mine = await Raw.connect(b)
        eid_b = await _publish_seen(b, mine, P.Publish(1, 1, (70,), 10_000, b"b1"))
        q = await Raw.connect(a)
        await q.send(P.Query(4, P.QUERY_CELLS, (10, 70)))
        r4 = await q.expect(P.QueryResult)
        assert sorted(u.entity for u in r4.entities) == sorted([eid, eid_b])
        assert a.cluster.core.stats["queries_partial"] == b.cluster.core.stats["queries_partial"] == 0


async def test_a_silent_shard_costs_the_wait_and_only_its_own_entities(nats_server):
    async with shards(nats_server.urls, two_regions(3)) as (a, b, c):
        pa, pc = await Raw.connect(a), await Raw.connect(c)
        eid_a = await _publish_seen(a, pa, P.Publish(1, 1, (5,), 10_000, b"a"))
        await _publish_seen(c, pc, P.Publish(1, 1, (90,), 10_000, b"c"))
        c.cluster.core._answer_query = lambda m, reply: None  # alive (heartbeats) but never answers a query
        asker = await Raw.connect(b)
        await asker.send(P.Query(1, P.QUERY_CELLS, (5, 90)))
        r = await asker.expect(P.QueryResult, timeout=5)  # answered at query_wait_s (0.5 s), not never
        assert [u.entity for u in r.entities] == [eid_a]  # what arrived in time
        assert b.cluster.core.stats["queries_partial"] == 1  # ... sent because the time was up
