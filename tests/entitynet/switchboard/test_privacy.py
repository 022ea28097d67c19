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


def test_empty_audience_sees_no_identities_reciprocity():
    """Who shows nobody sees nobody: a viewer sees an identity only if it shows its own to the owner too."""
    sb, alice, bob, carol, anon = _world()
    sb.receive(alice, [P.Privacy("Alice", None), pub(1, 1, (1,))], 0)
    assert recv(sb, bob)[0].identity == "Alice" and recv(sb, carol)[0].identity == "Alice"
    sb.receive(bob, [P.Privacy("Bob", ())], 0)  # bob shows his identity to nobody ...
    sb.receive(carol, [P.Privacy("Carol", ("dave",))], 0)  # ... carol only to dave, not to alice
    sb.receive(alice, [pub(1, 2, (1,))], 0)
    assert recv(sb, bob)[0].identity is None  # ... so neither sees alice's
    assert recv(sb, carol)[0].identity is None
    sb.receive(carol, [P.Privacy("Carol", ("dave", "alice"))], 0)
    sb.receive(alice, [pub(1, 3, (1,))], 0)
    assert recv(sb, carol)[0].identity == "Alice"  # mutual: shown
    # queries by identity follow the same rule
    sb.receive(bob, [P.Query(1, P.QUERY_IDENTITY, "Alice")], 0)
    assert of(recv(sb, bob), P.QueryResult)[0].entities == ()
    # an empty audience of the owner hides it from everyone, however they show themselves
    sb.receive(alice, [P.Privacy("Alice", ()), pub(1, 4, (1,))], 0)
    assert recv(sb, carol)[0].identity is None


def _authed():
    users = {"tok-a": "alice", "tok-b": "bob"}
    sb = make(open_mode=False, authenticate=users.get)
    return sb, users, join(sb, "tok-a"), join(sb, "tok-b")


def test_identity_bound_to_authenticated_user():
    """With tokens a client may publish only its own user id as identity; anyone else's is refused."""
    sb, users, alice, bob = _authed()
    sb.receive(bob, [P.Privacy("bob", None), P.Subscribe((1,), ())], 0)
    sb.receive(alice, [P.Privacy("bob", None)], 0)  # alice poses as bob
    (err,) = of(recv(sb, alice), P.Error)
    assert err.code == P.ErrorCode.NOT_OWNER and "not yours" in err.text
    sb.receive(alice, [pub(1, 1, (1,))], 0)  # the request was dropped, the connection lives
    assert recv(sb, bob)[0].identity is None
    assert sb.by_identity.get("bob") == {bob}
    sb.receive(bob, [P.Query(1, P.QUERY_IDENTITY, "bob")], 0)
    assert of(recv(sb, bob), P.QueryResult)[0].entities == ()  # nobody else answers to "bob"
    sb.receive(alice, [P.Privacy("alice", None), pub(1, 2, (1,))], 0)
    assert recv(sb, bob)[0].identity == "alice"


def test_open_mode_identities_unverified():
    sb, alice, bob, carol, anon = _world()  # open mode: "Alice" is not alice's user id, and that is allowed
    sb.receive(alice, [P.Privacy("Bob", None), pub(1, 1, (1,))], 0)
    assert recv(sb, carol)[0].identity == "Bob"
