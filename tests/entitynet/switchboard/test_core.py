"""The sans-IO switchboard: forwarding, LEAVE, snapshots, expiry, follows, queries, limits."""

from __future__ import annotations

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from tests.entitynet.switchboard_helpers import join, make, of, pub, recv


def test_publish_reaches_each_subscriber_once_and_not_the_owner():
    sb = make()
    a, v1, v2, v3 = (join(sb) for _ in range(4))
    sb.receive(v1, [P.Subscribe((1, 2, 3), ())], 0)
    sb.receive(v2, [P.Subscribe((3,), ())], 0)
    sb.receive(v3, [P.Subscribe((50,), ())], 0)
    sb.receive(a, [P.Subscribe((1, 2), ())], 0)
    sb.receive(a, [pub(7, 1, (1, 2, 3))], 0)
    u1, u2 = recv(sb, v1), recv(sb, v2)
    assert len(u1) == 1 and len(u2) == 1
    assert u1[0] == u2[0] and isinstance(u1[0], P.Update)
    assert u1[0].cells == (1, 2, 3) and u1[0].payload == b"s" and u1[0].identity is None
    assert u1[0].entity >= P.LOCAL_ID_LIMIT  # opaque server id, not the publisher's local id
    assert recv(sb, v3) == [] and recv(sb, a) == []


def test_leave_when_no_cell_is_shared_any_more():
    sb = make()
    a, v = join(sb), join(sb)
    sb.receive(v, [P.Subscribe((1, 2), ())], 0)
    sb.receive(a, [pub(1, 1, (1,))], 0)
    (u,) = recv(sb, v)
    sb.receive(a, [pub(1, 2, (2,))], 0)  # moved within the subscription: update, no leave
    assert [type(m) for m in recv(sb, v)] == [P.Update]
    sb.receive(a, [pub(1, 3, (5,))], 0)
    assert recv(sb, v) == [P.Leave(u.entity)]
    sb.receive(a, [pub(1, 4, (6,))], 0)
    assert recv(sb, v) == []


def test_coalescing_keeps_only_latest_state():
    sb = make()
    a, v = join(sb), join(sb)
    sb.receive(v, [P.Subscribe((1,), ())], 0)
    for seq in range(1, 6):
        sb.receive(a, [pub(1, seq, (1,), payload=bytes([seq]))], 0)
    got = recv(sb, v)
    assert len(got) == 1 and got[0].seq == 5 and got[0].payload == b"\x05"


def test_stale_sequence_is_dropped():
    sb = make()
    a, v = join(sb), join(sb)
    sb.receive(v, [P.Subscribe((1,), ())], 0)
    sb.receive(a, [pub(1, 5, (1,))], 0)
    recv(sb, v)
    sb.receive(a, [pub(1, 4, (1,)), pub(1, 5, (1,))], 0)
    assert recv(sb, v) == []
    assert sb.stats["stale"] == 2


def test_subscribe_diff_snapshot_each_entity_once_and_leave_on_removal():
    sb = make()
    a, b, v = join(sb), join(sb), join(sb)
    sb.receive(a, [pub(1, 1, (1, 2)), pub(2, 1, (3,))], 0)
    sb.receive(b, [pub(1, 1, (2,))], 0)
    sb.receive(v, [P.Subscribe((1, 2, 3, 9), ())], 0)
    snap = recv(sb, v)
    assert len(snap) == 3 and len({u.entity for u in snap}) == 3
    by_cells = {u.cells: u.entity for u in snap}
    # removing cell 1 keeps the entity in (1, 2): cell 2 is still shared; removing 3 makes entity 2 leave
    sb.receive(v, [P.Subscribe((4,), (1, 3))], 0)
    assert recv(sb, v) == [P.Leave(by_cells[(3,)])]
    # re-adding a cell whose occupant the client already sees sends nothing
    sb.receive(v, [P.Subscribe((1,), ())], 0)
    assert recv(sb, v) == []


def test_expiry_after_validity_plus_grace():
    sb = make(grace_s=2.0)
    a, v = join(sb), join(sb)
    sb.receive(v, [P.Subscribe((1,), ())], 0)
    sb.receive(a, [pub(1, 1, (1,), validity_ms=3000)], 10.0)
    (u,) = recv(sb, v)
    assert sb.next_deadline() == 15.0
    assert sb.expire(14.9) == 0
    sb.receive(a, [pub(1, 2, (1,), validity_ms=3000)], 14.0)  # renewed in time
    recv(sb, v)
    assert sb.expire(18.9) == 0
    assert sb.expire(19.0) == 1
    assert recv(sb, v) == [P.Leave(u.entity)]
    assert sb.counts()["entities"] == 0 and sb.occupants == {}


def test_timer_heap_stays_bounded_under_many_updates():
    sb = make()
    a = join(sb)
    for seq in range(20_000):
        sb.receive(a, [pub(seq % 3, seq + 1, (1,))], seq * 0.001)
    assert sb.timers.heap_size < 2 * 3 + 1024 + 1
    assert len(sb.timers) == 3


def test_disconnect_removes_entities_and_subscriptions():
    sb = make()
    a, v = join(sb), join(sb)
    sb.receive(v, [P.Subscribe((1,), ())], 0)
    sb.receive(a, [pub(1, 1, (1,))], 0)
    (u,) = recv(sb, v)
    sb.disconnect(a, 1)
    assert recv(sb, v) == [P.Leave(u.entity)]
    sb.disconnect(v, 1)
    assert sb.subscribers == {} and sb.entities == {} and sb.clients == {}


def test_publish_for_another_clients_entity_is_refused():
    sb = make()
    a, b, v = join(sb), join(sb), join(sb)
    sb.receive(v, [P.Subscribe((1,), ())], 0)
    sb.receive(a, [pub(1, 1, (1,))], 0)
    (u,) = recv(sb, v)
    sb.receive(b, [pub(u.entity, 99, (1,), payload=b"evil"), P.Unpublish(u.entity)], 0)
    errs = recv(sb, b)
    assert [e.code for e in errs] == [ErrorCode.NOT_OWNER, ErrorCode.NOT_OWNER]
    assert recv(sb, v) == [] and sb.entities[u.entity].payload == b"s"
    sb.receive(b, [P.Ping(1)], 0)  # not fatal
    assert of(recv(sb, b), P.Pong)


def test_nonexistent_cells_are_refused_without_side_effects():
    sb = make(n_cells=10)
    a = join(sb)
    sb.receive(a, [P.Subscribe((1, 10), ()), pub(1, 1, (3, 11)), P.Query(1, P.QUERY_CELLS, (12,))], 0)
    assert [e.code for e in recv(sb, a)] == [ErrorCode.NO_SUCH_CELL] * 3
    assert sb.subscribers == {} and sb.entities == {}


def test_subscription_limit():
    sb = make(max_subscriptions=5)
    a = join(sb)
    sb.receive(a, [P.Subscribe((1, 2, 3), ()), P.Subscribe((4, 5, 6), ()), P.Subscribe((4, 5), (1,))], 0)
    msgs = recv(sb, a)
    assert [e.code for e in of(msgs, P.Error)] == [ErrorCode.LIMIT_SUBSCRIPTIONS]
    assert sb.clients[a].subs == {2, 3, 4, 5}


def test_follow_regardless_of_cells_limit_and_unfollow():
    sb = make(max_follows=2)
    a, v = join(sb), join(sb)
    sb.receive(a, [pub(i, 1, (i,)) for i in range(1, 4)], 0)
    eids = sorted(sb.entities)
    sb.receive(v, [P.Follow(e) for e in eids], 0)
    msgs = recv(sb, v)
    assert len(of(msgs, P.Update)) == 2
    assert [e.code for e in of(msgs, P.Error)] == [ErrorCode.LIMIT_FOLLOWS]
    followed = {u.entity for u in of(msgs, P.Update)}
    sb.receive(a, [pub(i, 2, (i + 10,)) for i in range(1, 4)], 0)
    assert {u.entity for u in recv(sb, v)} == followed
    e0 = next(iter(followed))
    sb.receive(v, [P.Unfollow(e0), P.Follow(123456789012)], 0)
    msgs = recv(sb, v)
    assert P.Leave(e0) in msgs and [e.code for e in of(msgs, P.Error)] == [ErrorCode.NO_SUCH_ENTITY]


def test_query_by_cells_and_rate_limit():
    sb = make(query_rate=1.0, query_burst=2)
    a, q = join(sb), join(sb)
    sb.receive(a, [pub(1, 1, (1, 2)), pub(2, 1, (2,)), pub(3, 1, (9,))], 0)
    sb.receive(q, [P.Query(i, P.QUERY_CELLS, (1, 2)) for i in range(3)], 0)
    msgs = recv(sb, q)
    results = of(msgs, P.QueryResult)
    assert [r.query_id for r in results] == [0, 1] and len(results[0].entities) == 2
    assert [e.code for e in of(msgs, P.Error)] == [ErrorCode.QUERY_RATE]
    sb.receive(q, [P.Query(5, P.QUERY_CELLS, (9,))], 1.0)  # refilled
    assert len(of(recv(sb, q), P.QueryResult)[0].entities) == 1


def test_handshake_errors():
    sb = make(open_mode=False, authenticate={"good": "alice"}.get)
    c = sb.connect(0)
    sb.receive(c, [P.Ping(1)], 0)
    assert recv(sb, c)[0].code == ErrorCode.HANDSHAKE_REQUIRED and sb.outbox(c).close_after
    for hello, code in [
        (P.Hello(2, "good", "d"), ErrorCode.VERSION_MISMATCH),
        (P.Hello(1, "good", "other"), ErrorCode.TOPOLOGY_MISMATCH),
        (P.Hello(1, "bad", "d"), ErrorCode.AUTH_FAILED),
        (P.Hello(1, "", "d"), ErrorCode.AUTH_FAILED),
    ]:
        c = sb.connect(0)
        sb.receive(c, [hello, P.Subscribe((1,), ())], 0)
        (err,) = recv(sb, c)
        assert err.code == code and sb.outbox(c).close_after
        assert sb.subscribers == {}
    c = sb.connect(0)
    sb.receive(c, [P.Hello(1, "good", "d")], 0)
    assert isinstance(recv(sb, c)[0], P.Welcome) and sb.clients[c].user_id == "alice"


def test_server_to_client_message_from_client_closes():
    sb = make()
    a = join(sb)
    sb.receive(a, [P.Update(1, 1, (1,), 1, b"", None), P.Ping(1)], 0)
    msgs = recv(sb, a)
    assert [m.code for m in msgs] == [ErrorCode.UNKNOWN_TYPE]


def test_slow_consumer_overflow_is_dropped_and_others_unaffected():
    sb = make(max_pending=10)
    a, slow, ok = join(sb), join(sb), join(sb)
    sb.receive(slow, [P.Subscribe((1,), ())], 0)
    sb.receive(ok, [P.Subscribe((1,), ())], 0)
    for i in range(20):
        sb.receive(a, [pub(i, 1, (1,))], 0)
        assert len(recv(sb, ok)) == 1  # ok reads as it goes
    sb.take_dirty()
    msgs = P.decode_payload(P.payload_from_encoded(sb.outbox(slow).drain()))
    assert [m.code for m in msgs] == [ErrorCode.SLOW_CONSUMER] and sb.outbox(slow).close_after
    sb.receive(a, [pub(0, 2, (1,))], 0)
    assert len(recv(sb, ok)) == 1 and recv(sb, slow) == []


def test_many_entities_over_one_connection_and_entity_limit():
    sb = make(max_entities_per_client=100)
    a, v = join(sb), join(sb)
    sb.receive(v, [P.Subscribe(tuple(range(100)), ())], 0)
    sb.receive(a, [pub(i, 1, (i % 100,)) for i in range(101)], 0)
    msgs = recv(sb, a)
    assert [e.code for e in msgs] == [ErrorCode.LIMIT_ENTITIES]
    assert len(of(recv(sb, v), P.Update)) == 100
