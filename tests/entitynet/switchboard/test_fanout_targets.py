"""Forwarding to an unchanged viewer set costs one store per delivery, and the outbox handles stay exact.

Why: the PUBLISH hot path used to look every viewer's outbox up by client id on every delivery; the core now
keeps an `Outboxes.targets` handle with each entity's viewer set and reuses both while nobody (un)subscribed
to its cells or (un)followed it. These tests pin the saving (the lookups by client id happen once per viewer
set, not per delivery) and the exactness (after a subscription change, a follow, a disconnect, every client
gets exactly what it should, and nothing goes to a gone client).
"""

from __future__ import annotations

import pytest

from entitynet import protocol as P
from entitynet.switchboard import outbox
from tests.entitynet.switchboard_helpers import join, make, of, pub, recv


@pytest.fixture
def pure_fanout():
    """The pure-Python loops (the compiled ones read a dict subclass without calling its __getitem__)."""
    was = outbox.compiled_in_use()
    outbox.use_compiled(False)
    yield
    outbox.use_compiled(was)


class _CountingStates(dict):
    """The outboxes' client-id index, counting lookups."""

    lookups = 0

    def __getitem__(self, key):
        type(self).lookups += 1
        return super().__getitem__(key)


def test_publishes_reusing_the_viewer_set_look_its_outboxes_up_once(pure_fanout):
    sb = make()
    viewers = [join(sb) for _ in range(20)]
    for v in viewers:
        sb.receive(v, [P.Subscribe((3, 4), ())], 0.0)
        recv(sb, v)
    owner = join(sb)
    sb.receive(owner, [pub(1, 1, (3,))], 0.0)
    assert all(len(of(recv(sb, v), P.Update)) == 1 for v in viewers)
    counting = _CountingStates(sb.outboxes._states)  # the index behind `fan_out` (outbox.py's insides)
    sb.outboxes._states = counting
    _CountingStates.lookups = 0
    for seq in range(2, 12):
        sb.receive(owner, [pub(1, seq, (3,))], 0.0)
    assert _CountingStates.lookups <= len(viewers)  # resolved once, at the set's first reuse; on main: one
    # lookup per delivery (200 here)
    for v in viewers:
        ups = of(recv(sb, v), P.Update)
        assert [u.seq for u in ups] == [11]  # coalesced: the latest state once


def test_handles_follow_subscription_changes_follows_and_disconnects():
    sb = make()
    a, b, c = join(sb), join(sb), join(sb)
    sb.receive(a, [P.Subscribe((3,), ())], 0.0)
    sb.receive(b, [P.Subscribe((3,), ())], 0.0)
    owner = join(sb)
    sb.receive(owner, [pub(1, 1, (3,))], 0.0)
    eid = of(recv(sb, a), P.Update)[0].entity
    recv(sb, b)
    sb.disconnect(b, 0.1)  # b's outbox is gone: the next publish must not queue for it
    sb.receive(owner, [pub(1, 2, (3,))], 0.2)
    assert [u.seq for u in of(recv(sb, a), P.Update)] == [2]
    assert sb.outbox(b) is None
    sb.receive(c, [P.Subscribe((3,), ())], 0.3)  # snapshot now, and later updates
    assert [u.seq for u in of(recv(sb, c), P.Update)] == [2]
    sb.receive(owner, [pub(1, 3, (3,))], 0.4)
    assert [u.seq for u in of(recv(sb, a), P.Update)] == [3]
    assert [u.seq for u in of(recv(sb, c), P.Update)] == [3]
    sb.receive(a, [P.Subscribe((), (3,))], 0.5)  # a leaves the cell: LEAVE, then nothing more
    assert [m.entity for m in of(recv(sb, a), P.Leave)] == [eid]
    d = join(sb)
    sb.receive(d, [P.Follow(eid)], 0.6)  # a follower outside the cells joins the set
    assert [u.seq for u in of(recv(sb, d), P.Update)] == [3]
    sb.receive(owner, [pub(1, 4, (3,))], 0.7)
    assert recv(sb, a) == []
    assert [u.seq for u in of(recv(sb, c), P.Update)] == [4]
    assert [u.seq for u in of(recv(sb, d), P.Update)] == [4]


def test_entities_changing_cells_store_through_per_cell_handles(pure_fanout):
    """Most PUBLISHes of a moving entity change its cells, so its viewer set is new every time; the stores still
    go through handles, one per cell, made once per change of that cell's subscribers (on main: one lookup
    by client id per delivery). Overlapping cells give each viewer one UPDATE; an owner subscribed to its
    entity's cell gets none; a disconnect or a subscription change is followed exactly."""
    sb = make()
    viewers = [join(sb) for _ in range(10)]
    for i, v in enumerate(viewers):
        sb.receive(v, [P.Subscribe((3, 4) if i % 2 else (4, 5), ())], 0.0)
        recv(sb, v)
    owner = join(sb)
    sb.receive(owner, [pub(1, 1, (3, 4))], 0.0)  # all ten: five through cells 3 and 4, five through 4 only
    assert all(len(of(recv(sb, v), P.Update)) == 1 for v in viewers)
    counting = _CountingStates(sb.outboxes._states)  # the index behind `fan_out` (outbox.py's insides)
    sb.outboxes._states = counting
    _CountingStates.lookups = 0
    cells = [(4,), (4, 5), (3, 4), (4,), (4, 5), (3, 4), (5,)]
    for seq, cs in enumerate(cells, start=2):
        sb.receive(owner, [pub(1, seq, cs)], 0.0)
    assert _CountingStates.lookups <= 10 + 5 + 5  # cells 4, 5 and 3 resolved once each (on main: 60)
    for i, v in enumerate(viewers):
        got = recv(sb, v)
        if i % 2:  # (3, 4): lost it at (5,), the LEAVE replaced the pending UPDATE
            assert of(got, P.Update) == [] and len(of(got, P.Leave)) == 1
        else:  # (4, 5): once, coalesced to the latest state
            assert [u.seq for u in of(got, P.Update)] == [8] and of(got, P.Leave) == []
    sb.receive(owner, [P.Subscribe((3,), ())], 0.1)
    recv(sb, owner)
    sb.disconnect(viewers[0], 0.1)  # subscribed to (4, 5): its cells' handles must forget it
    sb.receive(viewers[2], [P.Subscribe((), (4, 5))], 0.1)
    recv(sb, viewers[2])
    sb.receive(owner, [pub(1, 20, (3, 4, 5))], 0.2)
    assert recv(sb, owner) == []  # never its own entity
    assert sb.outbox(viewers[0]) is None and of(recv(sb, viewers[2]), P.Update) == []
    assert all([u.seq for u in of(recv(sb, v), P.Update)] == [20] for v in (viewers[1], *viewers[3:]))
