"""The cluster core, sans-IO: several switchboards joined by an in-memory bus with NATS's subject semantics.

Deterministic (explicit `now`, no sockets): the failover rule, REDIRECT decisions, no echo, mirrors and their
expiry, snapshots, bad messages, a peer with another map, queries and follows that time out."""

from __future__ import annotations

import msgpack
import pytest

from entitynet import protocol as P
from entitynet.cluster.core import HEARTBEAT, STATE, ClusterCore
from tests.entitynet.switchboard_helpers import join, make, of, pub, recv

from .shard_helpers import two_regions


class Bus:
    """NATS in miniature: exact-subject interest, no echo to the publisher, replies to inboxes."""

    def __init__(self, k: int = 2, **kw):
        kw.setdefault("redirect_viewers", False)  # most tests watch one region from the other's shard
        self.regions = two_regions(k)
        self.sbs = [make(grace_s=0.5, seed=i + 1) for i in range(k)]
        self.cores = [ClusterCore(sb, self.regions, i, f"h:{i}", now=0.0, inbox=f"_INBOX.{i}", heartbeat_s=0.5,
                                  dead_after_s=2.0, **kw) for i, sb in enumerate(self.sbs)]
        p = self.cores[0].prefix
        self.subs = [{f"{p}.snap", f"{p}.hb", f"{p}.f", f"{p}.q", f"{p}.i", c.inbox} for c in self.cores]
        self.down: set[int] = set()
        self.published = 0
        self.cell_msgs = 0  # publications on cell subjects

    def run(self, now: float, rounds: int = 10) -> None:
        for _ in range(rounds):
            moved = False
            for i, core in enumerate(self.cores):
                if i in self.down:
                    core.take_out()
                    continue
                core.tick(now)
                add, rem = core.interest_changes()
                self.subs[i] |= set(add)
                self.subs[i] -= set(rem)
                for subject, data, reply in core.take_out():
                    moved = True
                    self.published += 1
                    self.cell_msgs += ".c." in subject
                    for j, other in enumerate(self.cores):
                        if j != i and j not in self.down and subject in self.subs[j]:
                            other.on_message(subject, reply, data, now)
                core.release_redirects()  # everything before them was delivered: the held REDIRECTs go out
            if not moved:
                return


@pytest.fixture
def bus():
    b = Bus()
    b.run(0.0)
    return b


def test_states_reach_the_other_shard_only_where_its_viewers_look(bus):
    a, b = bus.sbs
    p = join(a)
    v = join(b)
    a.receive(p, [pub(1, 1, (10,))], 0.1)
    bus.run(0.1)
    assert b.counts()["entities"] == 0  # nobody on b looks at cell 10: nothing crossed
    b.receive(v, [P.Subscribe((10,), ())], 0.2)
    bus.run(0.2)  # SUB + snapshot request -> a answers with its occupants of cell 10
    snap = of(recv(b, v), P.Update)
    assert [(u.seq, u.cells) for u in snap] == [(1, (10,))]
    a.receive(p, [pub(1, 2, (10,))], 0.3)
    bus.run(0.3)
    assert [u.seq for u in of(recv(b, v), P.Update)] == [2]
    assert a.stats["mirror_updates"] == 0 and bus.cores[0].stats["states_in"] == 0  # no echo


def test_mirrors_expire_like_local_entities(bus):
    a, b = bus.sbs
    v = join(b)
    b.receive(v, [P.Subscribe((10,), ())], 0.0)
    bus.run(0.0)
    p = join(a)
    a.receive(p, [pub(1, 1, (10,), validity_ms=1000)], 1.0)
    bus.run(1.0)
    eid = of(recv(b, v), P.Update)[0].entity
    assert b.expire(2.4) == 0  # validity 1 s + grace 0.5 s from t=1.0
    assert b.expire(2.6) == 1
    assert [m.entity for m in of(recv(b, v), P.Leave)] == [eid]


def test_the_failover_rule_is_the_same_on_every_survivor():
    bus = Bus(4)
    bus.run(0.0)
    bus.run(1.0)
    assert all(c.live_shards(1.0) == [0, 1, 2, 3] for c in bus.cores)
    bus.down = {2}
    for t in (1.5, 2.0, 2.5, 3.0, 3.5):
        bus.run(t)
    owners = {i: [c.owner_of(r, c.live_shards(3.5)) for r in range(4)] for i, c in enumerate(bus.cores)
              if i not in bus.down}
    assert owners[0] == owners[1] == owners[3] == [0, 1, 3, 3]  # live [0, 1, 3]: region 2 -> live[2 % 3]
    assert bus.cores[0].owned_regions(3.5) == [0]
    assert bus.cores[3].owned_regions(3.5) == [2, 3]


def test_a_dead_shards_mirrors_are_dropped_at_once(bus):
    a, b = bus.sbs
    v = join(b)
    b.receive(v, [P.Subscribe((10,), ())], 0.0)
    p = join(a)
    a.receive(p, [pub(1, 1, (10,), validity_ms=60_000)], 0.0)
    bus.run(0.0)
    assert len(of(recv(b, v), P.Update)) == 1
    bus.down = {0}
    bus.run(1.0)
    assert b.counts()["entities"] == 1  # not yet: 2 s without a heartbeat
    bus.run(2.6)
    assert b.counts()["entities"] == 0 and len(of(recv(b, v), P.Leave)) == 1
    assert bus.cores[1].owned_regions(2.6) == [0, 1]


def test_a_publisher_leaving_the_region_is_redirected_once_and_its_entity_leaves_first(bus):
    a, b = bus.sbs
    watcher = join(a)
    a.receive(watcher, [P.Subscribe((40, 60), ())], 0.0)
    p = join(a)
    a.receive(p, [pub(1, 1, (40,))], 0.1)
    a.receive(p, [pub(1, 2, (40, 60))], 0.2)  # straddling the border: still ours
    assert not of(recv(a, p), P.Redirect)
    a.receive(p, [pub(1, 3, (60,))], 0.3)
    assert not of(recv(a, p), P.Redirect) and a.counts()["entities"] == 0  # held until NATS has the LEAVE
    bus.run(0.3)
    red = of(recv(a, p), P.Redirect)
    assert [(r.shard, r.address) for r in red] == [(1, "h:1")]
    got = recv(a, watcher)
    assert isinstance(got[-1], P.Leave)  # the last word on the old id is its LEAVE
    a.receive(p, [pub(1, 4, (60,))], 0.4)  # in flight before the client moved: ignored
    assert a.counts()["entities"] == 0 and not recv(a, p)


def test_a_fleet_connection_is_not_redirected(bus):
    a = bus.sbs[0]
    p = join(a)
    a.receive(p, [pub(i, 1, (20,)) for i in range(1, 10)], 0.0)  # a proxy's 9 vehicles, in our region
    a.receive(p, [pub(i, 2, (70,)) for i in range(1, 10)], 0.1)  # all drive into b's: > MAX_REDIRECT_ENTITIES
    assert not of(recv(a, p), P.Redirect) and a.counts()["entities"] == 9


def test_viewer_redirect_follows_where_its_cells_are():
    bus = Bus(2, redirect_viewers=True)
    bus.run(0.0)
    a = bus.sbs[0]
    v = join(a)
    a.receive(v, [P.Subscribe(tuple(range(40, 55)), ())], 0.1)  # 10 of ours, 5 of b's
    assert not of(recv(a, v), P.Redirect)
    a.receive(v, [P.Subscribe(tuple(range(55, 75)), tuple(range(40, 50)))], 0.2)  # now mostly b's
    bus.run(0.2)
    assert [(r.shard, r.address) for r in of(recv(a, v), P.Redirect)] == [(1, "h:1")]


def test_bad_and_foreign_messages_are_counted_and_change_nothing(bus):
    core, sb = bus.cores[1], bus.sbs[1]
    p = core.prefix
    for data in (b"\xc1", msgpack.packb([]), msgpack.packb(["x", 0]), msgpack.packb([STATE, 0, 1, 2]),
                 msgpack.packb([STATE, 0, 1, 5, 1, [999], 10, b"", None, None, "u"]),  # cell beyond the map
                 msgpack.packb([99, 0])):
        core.on_message(f"{p}.c.1", None, data, 1.0)
    assert core.stats["bad_messages"] >= 4 and sb.counts()["entities"] == 0
    # a heartbeat of a shard with another cluster map is not a peer
    core.on_message(f"{p}.hb", None, msgpack.packb([HEARTBEAT, 0, "x:1", "other-map", {}]), 1.0)
    assert core.stats["peer_map_mismatch"] == 1


def test_query_and_follow_answer_in_time_without_the_peer():
    bus = Bus(2, query_wait_s=0.5, follow_wait_s=0.5)
    bus.run(0.0)
    b = bus.sbs[1]
    bus.down = {0}  # a does not answer (not yet declared dead)
    v = join(b, now=0.1)
    b.receive(v, [P.Query(3, P.QUERY_IDENTITY, "nobody"), P.Follow(P.LOCAL_ID_LIMIT + 7)], 0.1)
    bus.run(0.2)
    assert not recv(b, v)
    bus.run(0.7)
    got = recv(b, v)
    assert [m.query_id for m in of(got, P.QueryResult)] == [3]
    assert [e.code for e in of(got, P.Error)] == [P.ErrorCode.NO_SUCH_ENTITY]


def test_only_cells_another_shard_watches_go_out_on_nats(bus):
    a, b = bus.sbs
    core_a = bus.cores[0]
    p = join(a)
    before = bus.cell_msgs
    for seq in range(1, 6):
        a.receive(p, [pub(1, seq, (10,))], 0.1 * seq)  # nobody elsewhere looks at cell 10
        bus.run(0.1 * seq)
    assert core_a.stats["states_out"] == 5 and bus.cell_msgs == before  # no NATS traffic at all
    v = join(b)
    b.receive(v, [P.Subscribe((10,), ())], 1.0)
    bus.run(1.0)
    assert core_a.wanted[10] == 1
    assert [u.seq for u in of(recv(b, v), P.Update)] == [5]  # the snapshot
    a.receive(p, [pub(1, 6, (10,))], 1.1)
    bus.run(1.1)
    assert [u.seq for u in of(recv(b, v), P.Update)] == [6]  # then the live state
    b.receive(v, [P.Subscribe((), (10,))], 1.2)
    bus.run(1.2)
    assert core_a.wanted[10] == 0
    n = bus.cell_msgs
    a.receive(p, [pub(1, 7, (10,))], 1.3)
    bus.run(1.3)
    assert bus.cell_msgs == n  # b stopped looking: the cell is interior again


def test_a_new_publisher_in_another_region_is_redirected_before_anyone_sees_it(bus):
    a = bus.sbs[0]
    watcher = join(a)
    a.receive(watcher, [P.Subscribe((60,), ())], 0.0)
    p = join(a)
    a.receive(p, [pub(1, 1, (60,))], 0.1)  # region 1: b's
    assert a.counts()["entities"] == 0 and not recv(a, watcher)  # never published here
    # held until b is heard after the client came (alive, not dead): a asks b for its heartbeat now, and b's
    # answer (a NATS round trip, here 10 ms, not b's next scheduled heartbeat at 0.5) releases the REDIRECT
    bus.run(0.11)
    assert [(r.shard, r.address) for r in of(recv(a, p), P.Redirect)] == [(1, "h:1")]
    assert bus.cores[0].stats["heartbeats_asked"] == 1 and bus.cell_msgs == 0


def test_a_new_publisher_is_held_off_while_its_regions_owner_is_silent():
    bus = Bus(2)
    bus.run(0.0)
    bus.run(0.5)
    a = bus.sbs[0]
    bus.down = {1}  # b stops answering; not yet declared dead (2 s)
    p = join(a, now=1.0)
    a.receive(p, [pub(1, 1, (60,))], 1.6)  # b's last heartbeat was at 0.5: quiet for 1.1 s > 2 heartbeats
    assert a.counts()["entities"] == 0 and not of(recv(a, p), P.Redirect)
    assert bus.cores[0].stats["admissions_deferred"] == 1
    for t in (2.0, 2.6):
        bus.run(t)
    a.receive(p, [pub(1, 2, (60,))], 2.7)  # b declared dead: region 1 is a's now
    assert a.counts()["entities"] == 1


def test_every_request_wakes_the_shell_when_it_is_queued():
    """The shell holds publications for its latency budget but sends requests (a reply subject: a client waits
    on the answer) at once; so the core wakes it for each request, behind whatever is already queued, and the
    request is then the last publication queued."""
    bus = Bus(2)
    bus.run(0.0)
    core, b = bus.cores[1], bus.sbs[1]
    seen: list[str | None] = []
    core.wake = lambda: seen.append(core.out[-1][2] if core.out else "empty")
    v = join(b, now=0.1)
    b.receive(v, [P.Query(3, P.QUERY_IDENTITY, "nobody")], 0.1)
    b.receive(v, [P.Query(4, P.QUERY_IDENTITY, "somebody")], 0.1)
    assert [r for r in seen if r is not None and r != "empty"] == [core.inbox, core.inbox]
