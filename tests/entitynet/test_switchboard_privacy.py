"""The buddy rule: identities only for the audience, and only for clients that show their own."""

from __future__ import annotations

from entitynet import protocol as P
from tests.entitynet.switchboard_helpers import join, make, of, pub, recv


def _world():
    sb = make()
    alice, bob, carol, anon = join(sb, "alice"), join(sb, "bob"), join(sb, "carol"), join(sb, "")
    for c in (bob, carol, anon):
        sb.receive(c, [P.Subscribe((1,), ())], 0)
    sb.receive(bob, [P.Privacy("Bob", None)], 0)
    sb.receive(carol, [P.Privacy("Carol", None)], 0)
    return sb, alice, bob, carol, anon


def test_identity_shown_only_to_audience_that_shows_itself():
    sb, alice, bob, carol, anon = _world()
    sb.receive(alice, [P.Privacy("Alice", ("bob",)), pub(1, 1, (1,))], 0)
    assert recv(sb, bob)[0].identity == "Alice"
    assert recv(sb, carol)[0].identity is None  # not in the audience
    assert recv(sb, anon)[0].identity is None  # publishes no identity: sees none
    sb.receive(alice, [P.Privacy("Alice", None), pub(1, 2, (1,))], 0)
    assert recv(sb, carol)[0].identity == "Alice"
    assert recv(sb, anon)[0].identity is None
    sb.receive(alice, [P.Privacy(None, None), pub(1, 3, (1,))], 0)
    assert recv(sb, bob)[0].identity is None


def test_anonymous_by_default_and_ids_opaque_per_session():
    sb, alice, bob, carol, anon = _world()
    sb.receive(alice, [pub(1, 1, (1,))], 0)
    (u,) = recv(sb, bob)
    assert u.identity is None and u.entity != 1
    sb.disconnect(alice, 1)
    recv(sb, bob)
    alice2 = join(sb, "alice")
    sb.receive(alice2, [pub(1, 1, (1,))], 2)
    (u2,) = recv(sb, bob)
    assert u2.entity != u.entity  # a new session gives a new, unlinkable id


def test_query_by_identity_follows_buddy_rule():
    sb, alice, bob, carol, anon = _world()
    sb.receive(alice, [P.Privacy("Alice", ("bob",)), pub(1, 1, (7,))], 0)
    sb.receive(bob, [P.Query(1, P.QUERY_IDENTITY, "Alice")], 0)
    sb.receive(carol, [P.Query(1, P.QUERY_IDENTITY, "Alice")], 0)
    sb.receive(anon, [P.Query(1, P.QUERY_IDENTITY, "Alice")], 0)
    (rb,) = of(recv(sb, bob), P.QueryResult)
    assert len(rb.entities) == 1 and rb.entities[0].identity == "Alice" and rb.entities[0].cells == (7,)
    assert of(recv(sb, carol), P.QueryResult)[0].entities == ()
    assert of(recv(sb, anon), P.QueryResult)[0].entities == ()
    # bob may now follow the buddy he found
    sb.receive(bob, [P.Follow(rb.entities[0].entity)], 0)
    assert recv(sb, bob)[0].identity == "Alice"
