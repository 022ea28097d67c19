"""Two and three shard servers over one real nats-server on loopback: mirrors, snapshots, no echo, expiry,
follow and query across shards, privacy, roaming (REDIRECT) and a killed switchboard."""

from __future__ import annotations

import trio

from entitynet import protocol as P
from tests.entitynet.server_helpers import Raw

from .shard_helpers import shards, two_regions, until


async def _view(server, *cells: int) -> Raw:
    v = await Raw.connect(server)
    await v.send(P.Subscribe(tuple(cells), ()))
    await v.send(P.Ping(1))
    await v.expect(P.Pong)
    return v


async def _settled(*servers) -> None:
    """Every shard's NATS interest is in place (SUBs reached the server)."""
    await trio.sleep(0.05)
    for s in servers:
        await s.cluster.nc.flush()


async def test_snapshot_updates_and_leave_cross_shards_without_echo(nats_server):
    async with shards(nats_server.urls, two_regions()) as (a, b):
        pub = await Raw.connect(a)
        local = await _view(a, 10)
        await pub.send(P.Publish(1, 1, (10,), 10_000, b"one"))  # before anyone on b looks: b needs a snapshot
        u = await local.expect(P.Update)
        eid = u.entity
        remote = await _view(b, 10)
        snap = await remote.expect(P.Update)
        assert (snap.entity, snap.seq, snap.payload, snap.cells) == (eid, 1, b"one", (10,))
        await _settled(a, b)
        for seq in range(2, 6):
            await pub.send(P.Publish(1, seq, (10,), 10_000, b"%d" % seq))
            up = await remote.expect(P.Update, pred=lambda m, s=seq: m.seq == s)
            assert up.entity == eid and up.payload == b"%d" % seq
        # an entity in two cells is delivered once per state, whatever number of cell subjects carried it
        remote2 = await _view(b, 10, 11)
        await remote2.expect(P.Update)
        await _settled(a, b)
        await pub.send(P.Publish(1, 6, (10, 11), 10_000, b"six"))
        await remote2.expect(P.Update, pred=lambda m: m.seq == 6)
        await pub.send(P.Publish(1, 7, (11,), 10_000, b"seven"))
        await remote2.expect(P.Update, pred=lambda m: m.seq == 7)
        await remote2.send(P.Ping(2))
        await remote2.expect(P.Pong)
        seqs = [m.seq for m in remote2.pending if isinstance(m, P.Update)]
        assert seqs == sorted(set(seqs)), f"a state was delivered twice: {seqs}"
        # leaving cell 10 for 11 is seen by b's viewer of 10 as a LEAVE (the publication went to the left cell)
        gone = await remote.expect(P.Leave)
        assert gone.entity == eid
        await pub.send(P.Unpublish(1))
        await remote2.expect(P.Leave, pred=lambda m: m.entity == eid)
        # no echo: a never mirrored its own entity; b mirrored it and holds nothing now
        assert a.sb.stats["mirror_updates"] == 0
        assert b.sb.stats["mirror_updates"] >= 5
        await until(lambda: eid not in b.sb.entities)


async def test_mirrored_entity_expires_with_its_validity(nats_server):
    async with shards(nats_server.urls, two_regions()) as (a, b):
        remote = await _view(b, 20)
        await _settled(a, b)
        pub = await Raw.connect(a)
        await pub.send(P.Publish(1, 1, (20,), 300, b"short"))  # 0.3 s + 0.2 s grace, then silence
        u = await remote.expect(P.Update)
        t0 = trio.current_time()
        lv = await remote.expect(P.Leave, timeout=3)
        assert lv.entity == u.entity
        assert 0.3 <= trio.current_time() - t0 < 2.0


async def test_follow_and_query_by_identity_across_shards_with_the_buddy_rule(nats_server):
    async with shards(nats_server.urls, two_regions()) as (a, b):
        alice = await Raw.connect(a)  # open mode: the token is the user id ("" here), identities are free
        await alice.send(P.Privacy("alice", ("bob",)), P.Publish(1, 1, (5,), 10_000, b"a1"))
        local = await _view(a, 5)
        eid = (await local.expect(P.Update)).entity
        bob = await Raw.connect(b, token="bob")
        await bob.send(P.Privacy("bob", None))
        carol = await Raw.connect(b, token="carol")
        await carol.send(P.Privacy("carol", None))
        # FOLLOW of an entity b has never seen (nobody on b subscribes to cell 5): b asks the cluster
        await bob.send(P.Follow(eid))
        f = await bob.expect(P.Update, pred=lambda m: m.entity == eid)
        assert f.identity == "alice"  # bob is in alice's audience and shows himself to everyone
        await _settled(a, b)
        await alice.send(P.Publish(1, 2, (6,), 10_000, b"a2"))
        g = await bob.expect(P.Update, pred=lambda m: m.seq == 2)
        assert g.entity == eid and g.cells == (6,)
        # QUERY by identity: bob finds alice on the other shard; carol (not in her audience) does not
        await bob.send(P.Query(7, P.QUERY_IDENTITY, "alice"))
        r = await bob.expect(P.QueryResult)
        assert [m.entity for m in r.entities] == [eid] and r.entities[0].identity == "alice"
        await carol.send(P.Query(8, P.QUERY_IDENTITY, "alice"))
        r2 = await carol.expect(P.QueryResult)
        assert r2.entities == ()
        # and carol following her gets the entity, anonymous
        await carol.send(P.Follow(eid))
        h = await carol.expect(P.Update, pred=lambda m: m.entity == eid)
        assert h.identity is None
        # a FOLLOW of an entity nobody owns is refused, as on one server
        await bob.send(P.Follow(P.LOCAL_ID_LIMIT + 12345))
        err = await bob.expect(P.Error, timeout=5)
        assert err.code == P.ErrorCode.NO_SUCH_ENTITY


async def test_a_publisher_roaming_into_another_region_is_redirected(nats_server):
    from entitynet.connection import Connection
    from tests.entitynet.server_helpers import DIGEST

    async with shards(nats_server.urls, two_regions()) as (a, b):
        watch_a = await _view(a, 40, 60)  # one viewer on each shard sees both sides of the border
        watch_b = await _view(b, 40, 60)
        await _settled(a, b)
        redirects: list[P.Redirect] = []
        conn = Connection(("127.0.0.1", a.port), DIGEST, backoff=(0.01, 0.05),
                          on_message=lambda m: redirects.append(m) if isinstance(m, P.Redirect) else None)
        async with trio.open_nursery() as n:
            await n.start(conn.run)
            await conn.publish(P.Publish(1, 1, (40,), 10_000, b"west"))
            first = await watch_b.expect(P.Update)
            await conn.publish(P.Publish(1, 2, (60,), 10_000, b"east"))  # region 1: b's
            await until(lambda: redirects, timeout=5)
            assert redirects[0].shard == 1 and redirects[0].address == f"127.0.0.1:{b.port}"
            await until(lambda: any(e.owner.mirror is None for e in b.sb.entities.values()), timeout=5)
            await conn.publish(P.Publish(1, 3, (60,), 10_000, b"east2"))
            # each watcher: the old id leaves, the new one appears, never both at once
            for w in (watch_a, watch_b):
                visible: set[int] = set()
                log: list = []
                with trio.fail_after(5):
                    batch, w.pending = w.pending, []
                    while True:
                        for m in batch:
                            if isinstance(m, P.Update):
                                visible.add(m.entity)
                            elif isinstance(m, P.Leave):
                                visible.discard(m.entity)
                            log.append(m)
                            assert len(visible) <= 1, f"an entity was shown twice: {log}"
                        if any(isinstance(m, P.Update) and m.seq == 3 for m in batch):
                            break
                        batch = await w.read()
                assert visible and first.entity not in visible
            assert a.sb.stats["redirects"] == 1
            n.cancel_scope.cancel()


async def test_a_killed_switchboard_is_dropped_and_its_clients_recover_on_the_survivors(nats_server):
    from entitynet.connection import Connection
    from tests.entitynet.server_helpers import DIGEST

    async with shards(nats_server.urls, two_regions(3)) as (a, b, c):
        watch = await _view(a, 80)
        await _settled(a, b, c)
        redirects: list[P.Redirect] = []
        # the client of c knows another shard of the cluster (b): where it fails over, as soon as c refuses a
        # redial (not after failover_s, 30 s here: the time rule is for shards that do not answer at all)
        conn = Connection(("127.0.0.1", c.port), DIGEST, backoff=(0.05, 0.1), alternates=(("127.0.0.1", b.port),),
                          failover_s=30.0,
                          on_message=lambda m: redirects.append(m) if isinstance(m, P.Redirect) else None)
        async with trio.open_nursery() as n:
            await n.start(conn.run)
            await conn.publish(P.Publish(1, 1, (80,), 60_000, b"on c"))  # region 2, c's
            eid = (await watch.expect(P.Update)).entity
            killed_at = trio.current_time()
            c.kill_scope.cancel()  # no goodbye: its connections drop, its heartbeats stop
            # the viewer's stream, in order: the old copy leaves (after dead_after_s, not its 60 s validity)
            # before the new one arrives, re-published through b, which held it until c was declared dead
            # and then REDIRECTed it to a, region 2's new owner
            visible, doubled, back = {eid}, 0, None
            with trio.fail_after(10):
                while back is None:
                    for m in list(watch.pending) + (await watch.read(5) or []):
                        if isinstance(m, P.Leave):
                            visible.discard(m.entity)
                        elif isinstance(m, P.Update) and m.payload == b"on c":
                            doubled += bool(visible - {m.entity})
                            visible.add(m.entity)
                            if m.entity != eid:
                                back = m
                    watch.pending = []
            recovery = trio.current_time() - killed_at
            assert doubled == 0 and visible == {back.entity}
            core_a, core_b = a.cluster.core, b.cluster.core
            live = core_a.live_shards(a.clock())
            assert live == core_b.live_shards(b.clock()) == [0, 1]
            assert core_a.owner_of(2, live) == core_b.owner_of(2, live) == 0  # 2 % 2: the same rule everywhere
            assert back.entity != eid and back.entity in a.sb.entities
            assert a.sb.entities[back.entity].owner.mirror is None
            # held by b until c was declared dead, then sent to a: never back to the dead c
            assert [(r.shard, r.address) for r in redirects] == [(0, f"127.0.0.1:{a.port}")]
            assert recovery < 5.0  # about dead_after_s (0.6 s) here; a generous bound that is not 30 s
            n.cancel_scope.cancel()


async def test_a_killed_nats_node_is_replaced_without_losing_the_switchboards(nats_cluster3):
    from .shard_helpers import shards_on

    nodes = nats_cluster3.nodes
    # shard a knows node 0 only (it learns the others from INFO), shard b node 1
    async with shards_on([nodes[0].url, nodes[1].url], two_regions()) as (a, b):
        pub = await Raw.connect(a)
        remote = await _view(b, 30)
        await _settled(a, b)
        seq = 1
        with trio.fail_after(10):  # until interest has crossed the routes (a delay that depends on the load)
            while True:
                await pub.send(P.Publish(1, seq, (30,), 10_000, b"before"))
                try:
                    eid = (await remote.expect(P.Update, timeout=0.3)).entity
                    break
                except trio.TooSlowError:
                    seq += 1
        nodes[0].kill()
        await until(lambda: a.cluster.nc.connected and a.cluster.nc.server[1] != nodes[0].port, timeout=10)
        assert a.cluster.nc.reconnects == 1
        # b never lost a: no peer was declared dead, the mirror was not dropped
        await trio.sleep(0.3)
        assert b.cluster.core.stats["peers_lost"] == 0 and eid in b.sb.entities
        seq += 1
        with trio.fail_after(10):  # until the new route carries a's publications again
            while True:
                await pub.send(P.Publish(1, seq, (30,), 10_000, b"after"))
                try:
                    u = await remote.expect(P.Update, pred=lambda m, s=seq: m.seq == s, timeout=0.3)
                    break
                except trio.TooSlowError:
                    seq += 1
        assert u.entity == eid and u.payload == b"after"
