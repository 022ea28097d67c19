"""Failover in the cluster core, sans-IO (entitynet.cluster.failover): the survivors of a dead shard decide
together, and a client failing over early is held, not refused.

Deterministic: an in-memory bus and explicit times; each survivor's clock is stepped on its own, since in a
real cluster their heartbeat timers are not in phase (that is what produced duplicates)."""

from __future__ import annotations

from entitynet import protocol as P
from tests.entitynet.switchboard_helpers import join, of, pub, recv

from .test_core import Bus


def step(bus: Bus, i: int, now: float) -> None:
    """Shard `i` alone runs its timers at `now`; what it publishes is delivered to the others at once (they do
    not tick: their own timers are still ahead)."""
    core = bus.cores[i]
    core.tick(now)
    add, rem = core.interest_changes()
    bus.subs[i] |= set(add)
    bus.subs[i] -= set(rem)
    for subject, data, reply in core.take_out():
        for j, other in enumerate(bus.cores):
            if j != i and j not in bus.down and subject in bus.subs[j]:
                other.on_message(subject, reply, data, now)
    core.release_redirects()


def _three_with_a_mirror():
    """Shards 0, 1, 2 (cells 67.. are region 2); a viewer on 1 watches cell 80, where a client of 2 publishes."""
    bus = Bus(3)
    bus.run(0.0)
    a, b, c = bus.sbs
    v = join(b)
    b.receive(v, [P.Subscribe((80,), ())], 0.0)
    bus.run(0.0)
    p = join(c)
    c.receive(p, [pub(1, 1, (80,), validity_ms=60_000, payload=b"gid-7")], 0.5)
    bus.run(0.5)
    (u,) = of(recv(b, v), P.Update)
    bus.down = {2}  # SIGKILL: no more heartbeats; its last one was at 0.5, so it is dead from 2.5 on
    step(bus, 1, 1.0)  # 0 and 1 keep hearing each other
    step(bus, 0, 1.0)
    return bus, v, u.entity


def test_a_survivor_that_declares_a_shard_dead_tells_the_others_before_its_clients_states():
    bus, v, old = _three_with_a_mirror()
    a, b, _ = bus.sbs
    step(bus, 1, 2.0)  # shard 1's timers ran just before the deadline: it still holds 2 alive
    assert bus.cores[1].peers[2].alive
    step(bus, 0, 2.5)  # shard 0 decides first: region 2 is live[2 % 2] = 0's now
    p = join(a, now=2.5)
    a.receive(p, [pub(1, 1, (80,), validity_ms=60_000, payload=b"gid-7")], 2.5)  # the client re-publishes on 0
    step(bus, 0, 2.5)
    new = [e for e in b.entities if e != old]
    assert len(new) == 1 and b.entities[new[0]].owner.mirror == 0
    # shard 1's own deadline has not come, yet the dead shard's copy is gone before the new one arrived: the
    # viewer never holds the entity under two ids (before: both, until shard 1's next tick)
    assert old not in b.entities
    got = recv(b, v)
    assert [type(m) for m in got if m.entity in (old, new[0])] == [P.Leave, P.Update]
    assert bus.cores[1].stats["peers_lost"] == 1


def test_the_word_of_a_dead_shard_is_not_taken_for_one_heard_recently():
    bus = Bus(3)
    bus.run(0.0)
    bus.run(0.5)
    bus.down = {2}  # shard 0 no longer hears 2 ...
    step(bus, 1, 2.0)
    core0, core1 = bus.cores[0], bus.cores[1]
    core1._heartbeat(2, [5, 2, "h:2", bus.regions.digest, {}, []], 2.4)  # ... but 1 does (a partition of 0's)
    step(bus, 0, 2.5)
    assert not core0.peers[2].alive  # 0 decided, and said so
    assert core1.peers[2].alive and core1.stats["peers_lost"] == 0  # 1 heard 2 0.1 s ago: not believed


def test_a_client_failing_over_early_is_held_and_served_the_moment_the_owner_is_decided():
    bus, v, old = _three_with_a_mirror()
    a, b, _ = bus.sbs
    p = join(a, now=1.6)
    a.receive(p, [pub(1, 1, (80,), validity_ms=60_000, payload=b"gid-7")], 1.6)  # 2 quiet for 1.1 s: held
    assert a.counts()["entities"] == 0 and not of(recv(a, p), P.Redirect)
    step(bus, 0, 2.5)  # 2 is dead: the held PUBLISH is served here without the client sending it again
    assert a.counts()["entities"] == 1
    (e,) = [x for x in a.entities.values() if x.owner.mirror is None]
    assert e.validity_ms == 59_100  # shortened by the time it was held
    assert old not in b.entities and e.eid in b.entities  # shard 1 dropped the old copy first


def test_a_held_client_whose_region_went_to_another_survivor_is_redirected_there():
    bus, v, old = _three_with_a_mirror()
    b = bus.sbs[1]
    p = join(b, now=1.6)
    b.receive(p, [pub(1, 1, (80,), validity_ms=60_000)], 1.6)  # failing over to 1; region 2 will be 0's
    step(bus, 1, 1.6)
    assert not of(recv(b, p), P.Redirect)  # not to the quiet shard 2: it would only fail over again
    step(bus, 0, 2.0)
    step(bus, 1, 2.5)
    assert [(r.shard, r.address) for r in of(recv(b, p), P.Redirect)] == [(0, "h:0")]
    assert b.counts()["entities"] == 0  # never published on 1


def test_a_client_failing_over_at_once_is_not_sent_back_to_the_dead_shard():
    """0.1 s after the kill shard 2 is not yet quiet, but it has not been heard since the client came: the
    client is held (before: REDIRECTed to the dead shard, to fail over again), then sent to the new owner."""
    bus, v, old = _three_with_a_mirror()
    b = bus.sbs[1]
    p = join(b, now=0.6)
    b.receive(p, [pub(1, 1, (80,), validity_ms=60_000)], 0.6)
    step(bus, 1, 0.6)
    assert not of(recv(b, p), P.Redirect) and b.counts()["entities"] == 1  # the mirror only
    step(bus, 0, 2.0)
    step(bus, 1, 2.5)
    assert [(r.shard, r.address) for r in of(recv(b, p), P.Redirect)] == [(0, "h:0")]


def test_death_is_declared_at_its_deadline_not_at_the_next_heartbeat():
    bus = Bus(2)
    bus.run(0.0)
    step(bus, 1, 0.5)  # shard 1's last heartbeat: dead from 2.5 on
    bus.down = {1}
    core = bus.cores[0]
    core.tick(0.6)  # shard 0's own heartbeats are out of phase: 0.6, 1.1, 1.6, 2.1, 2.6
    core.tick(2.1)
    assert core.next_deadline() == 2.5  # the deadline itself, not the heartbeat after it (2.6)
    core.tick(2.5)
    assert not core.peers[1].alive and core.owned_regions(2.5) == [0, 1]


def test_leaves_written_to_a_nats_node_that_died_are_published_again_after_the_reconnect():
    """A LEAVE that died with a NATS node would leave its mirror on the other shards until its validity ran out,
    beside the entity's new copy once its client re-published elsewhere (a duplicate): after a reconnect the
    recent LEAVEs go out again, and the other shard drops the mirror."""
    bus = Bus(2)
    bus.run(0.0)
    a, b = bus.sbs
    v = join(b)
    b.receive(v, [P.Subscribe((10,), ())], 0.0)
    bus.run(0.0)
    p = join(a)
    a.receive(p, [pub(1, 1, (10,), validity_ms=60_000)], 0.1)
    bus.run(0.1)
    (u,) = of(recv(b, v), P.Update)
    a.disconnect(p, 0.2)  # its entity leaves
    bus.cores[0].take_out()  # the LEAVE was written to the node that died: nobody got it
    bus.run(0.3)
    assert u.entity in b.entities  # the mirror stays (until its 60 s validity)
    bus.cores[0].resync()  # NATS reconnected
    bus.run(0.4)
    assert u.entity not in b.entities and of(recv(b, v), P.Leave)
    assert bus.cores[0].stats["leaves_resent"] == 1


def test_a_mirror_that_moves_out_of_every_watched_cell_is_forgotten_not_left_as_a_ghost():
    """Its owner publishes later states and its LEAVE only to the cells it is in, which this shard does not
    watch: kept, the mirror lingered unseen for validity + grace, and a viewer failing over onto this shard and
    subscribing to its cell was shown it beside the entity's real copy (the duplicates of issue 13's failover)."""
    bus = Bus(2)
    bus.run(0.0)
    a, b = bus.sbs
    v = join(b)
    b.receive(v, [P.Subscribe((10,), ())], 0.0)
    bus.run(0.0)
    p = join(a)
    a.receive(p, [pub(1, 1, (10,), validity_ms=60_000, payload=b"g")], 0.1)
    bus.run(0.1)
    (u,) = of(recv(b, v), P.Update)
    a.receive(p, [pub(1, 2, (20,), validity_ms=60_000, payload=b"g")], 0.2)  # out of b's view
    bus.run(0.2)
    assert of(recv(b, v), P.Leave) and u.entity not in b.entities  # forgotten at once, not in 65 s
    a.disconnect(p, 0.3)  # its LEAVE goes to cell 20 only: b does not watch it
    bus.run(0.3)
    refugee = join(b, now=0.4)
    b.receive(refugee, [P.Subscribe((20,), ())], 0.4)
    bus.run(0.4)
    assert not of(recv(b, refugee), P.Update)  # no ghost
