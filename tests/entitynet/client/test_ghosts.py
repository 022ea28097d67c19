"""Receiver side: ghost store (keep invisible entities for their validity) and subscriptions."""

import pytest

from entitynet.client import GhostStore, LimitExceeded, Player, Subscriptions, WorldModel, encode, netview
from entitynet.protocol import QUERY_IDENTITY, Follow, Leave, Subscribe, Update
from tests.entitynet.client_fixtures import cross


def upd(entity, seq, cells, validity_ms, t0=0.0, x=0.0):
    return Update(entity, seq, cells, validity_ms, encode(WorldModel(t0, x, 0.0, 1.0, 0.0, 0.0, 0.0, 1)))


def test_ghost_kept_while_invisible_and_reappears_until_validity_expires():
    gs = GhostStore(None)
    gs.set_visible({1})
    gs.receive(upd(5, 1, (1,), 10_000), now=0.0)
    assert gs.positions(1.0) == {5: pytest.approx((1.0, 0.0))}
    gs.set_visible({2})  # the cell becomes invisible: not drawn, but kept
    assert gs.positions(2.0) == {}
    assert len(gs) == 1
    gs.set_visible({1, 2})  # visible again: drawn at once, extrapolated
    assert gs.positions(3.0) == {5: pytest.approx((3.0, 0.0))}
    assert gs.positions(10.0) == {} and len(gs) == 0  # validity ran out: dropped


def test_out_of_order_updates_leave_and_bad_payloads():
    gs = GhostStore(None)
    gs.receive(upd(5, 2, (1,), 10_000, x=20.0), 0.0)
    gs.receive(upd(5, 1, (1,), 10_000, x=99.0), 0.0)  # older seq: ignored
    assert gs.positions(0.0, visible_only=False)[5] == pytest.approx((20.0, 0.0))
    gs.receive(Update(6, 1, (1,), 1000, b"\xc1garbage"), 0.0)
    assert gs.bad_payloads == 1 and 6 not in gs.ghosts
    gs.receive(Leave(5), 0.0)
    assert len(gs) == 0


def test_receiver_ghost_equals_the_players_own_ghost():
    topo = cross(arm=300.0)
    p = Player(topo, 1, "tram")
    gs = GhostStore(netview(topo))
    for i in range(20):
        for m in p.feed(-250.0 + 8.0 * i, 0.0, float(i)):
            gs.receive(Update(100, m.seq, m.cells, m.validity_ms, m.payload), float(i))
    g = gs.ghosts[100]
    for t in (19.0, 20.5, 22.0):
        assert g.model.xy_at(t) == p.ghost.xy_at(t)


def test_subscriptions_send_the_difference_only():
    pvs = {0: [1, 2, 3], 1: [2, 3, 4]}
    subs = Subscriptions(lambda x, y, z: pvs[int(x // 100)])
    assert subs.move_camera(10.0, 0.0, 2.0) == [Subscribe((1, 2, 3), ())]
    assert subs.move_camera(20.0, 0.0, 2.0) == []
    assert subs.move_camera(150.0, 0.0, 2.0) == [Subscribe((4,), (1,))]
    with pytest.raises(ValueError):
        subs.move_camera(float("nan"), 0.0, 0.0)


def test_follow_limit_and_query_rate():
    subs = Subscriptions(lambda x, y, z: [], max_follows=2, query_interval=5.0)
    assert subs.follow(1) == [Follow(1)] and subs.follow(1) == []
    subs.follow(2)
    with pytest.raises(LimitExceeded):
        subs.follow(3)
    assert subs.unfollow(2) and subs.follow(3) == [Follow(3)]
    (q,) = subs.query(0.0, identity="bob")
    assert q.kind == QUERY_IDENTITY and q.arg == "bob"
    with pytest.raises(LimitExceeded):
        subs.query(4.0, cells=[1])
    assert subs.query(5.0, cells=[3, 1, 3])[0].arg == (1, 3)
