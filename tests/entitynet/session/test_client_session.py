"""The sans-IO client session driven deterministically, without sockets: replay after a reconnect, SUBSCRIBE
diffs, backoff, final vs retryable errors, REDIRECT moving entities or the viewer, the clock offset, bad input."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from entitynet import protocol as P
from entitynet.session import (
    Answer,
    ClientSession,
    Connect,
    Deliver,
    Drop,
    Notice,
    ReconnectPolicy,
    Send,
    Stop,
    parse_address,
)

HOME = ("127.0.0.1", 7400)
OTHER = ("10.0.0.2", 7401)
WELCOME = P.Welcome(1, 1, 0)


def _sent(actions, link=None):
    """The messages of all Send actions (of one link), flattened."""
    return [m for a in actions if type(a) is Send and (link is None or a.link == link) for m in a.msgs]


def _of(actions, kind):
    return [a for a in actions if type(a) is kind]


def _open(s: ClientSession, now: float = 0.0, address=HOME) -> tuple[int, list]:
    """Start (if needed), connect and welcome the link to `address`; returns (link, actions of the WELCOME)."""
    acts = s.start(now) if not s._links else []
    acts = acts + s.timers(now)
    link = next(a.link for a in acts if type(a) is Connect and a.address == address)
    hello = s.connection_made(link, now)
    assert _sent(hello) == [P.Hello(P.PROTOCOL_VERSION, "tok", "dig")]
    return link, s.receive(link, [WELCOME], now)


def _session(**kw) -> ClientSession:
    return ClientSession(HOME, "dig", "tok", **kw)


def test_replay_after_reconnect_shortens_validity_and_keeps_order():
    s = _session(policy=ReconnectPolicy(0.1, 5.0))
    s.set_privacy("me", ["friend"])
    s.subscribe((3, 1, 2))
    s.follow(99)
    assert s.publish([P.Publish(7, 1, (1,), 10_000, b"a")], 0.0) == []  # not connected: remembered only
    link, acts = _open(s, 1.0)
    assert _sent(acts, link)[:4] == [P.Privacy("me", ("friend",)), P.Subscribe((1, 2, 3), ()), P.Follow(99),
                                     P.Publish(7, 1, (1,), 9_000, b"a")]
    assert _of(acts, Deliver) == [Deliver(WELCOME)] and s.connected and s.connects == 1
    # a newer state while connected goes out at once and replaces the remembered one
    acts = s.publish([P.Publish(7, 2, (2,), 10_000, b"b")], 2.0)
    assert acts == [Send(link, (P.Publish(7, 2, (2,), 10_000, b"b"),))]
    s.connection_lost(link, 3.0, "reset")
    assert not s.connected
    assert s.publish([P.Publish(8, 1, (4,), 5_000, b"c")], 3.0) == []
    link2, acts = _open(s, 3.5)
    assert link2 != link and s.connects == 2
    assert _sent(acts, link2)[3:5] == [P.Publish(7, 2, (2,), 8_500, b"b"), P.Publish(8, 1, (4,), 4_500, b"c")]
    # an entity whose validity ran out while away is replayed with 0, not a negative time
    s.connection_lost(link2, 4.0)
    link3, acts = _open(s, 60.0)
    assert [m.validity_ms for m in _sent(acts, link3) if type(m) is P.Publish] == [0, 0]


def test_replay_frames_stay_within_the_frame_limit():
    """1,000 entities with 2 KiB payloads (about 2 MB) replay as several frames, each within the server's
    announced max_frame: one frame of them all would be refused with FRAME_TOO_LARGE on every reconnect."""
    s = _session()
    for e in range(1000):
        s.publish([P.Publish(e, 1, (e % 50,), 10_000, bytes(2048))], 0.0)
    acts = s.start(0.0) + s.timers(0.0)
    link = next(a.link for a in acts if type(a) is Connect)
    s.connection_made(link, 0.0)
    acts = s.receive(link, [P.Welcome(1, 1, 0, {"max_frame": 500_000})], 0.0)
    frames = [a.msgs for a in acts if type(a) is Send and a.link == link]
    sizes = [len(P.encode_payload(f)) for f in frames]
    assert max(sizes) <= 500_000 and len(frames) >= 5
    assert sorted(m.entity for f in frames for m in f if type(m) is P.Publish) == list(range(1000))


def test_unpublished_entity_is_not_replayed():
    s = _session()
    link, _ = _open(s)
    s.publish([P.Publish(1, 1, (1,), 1000, b"x"), P.Publish(2, 1, (1,), 1000, b"y")], 0.0)
    assert s.unpublish(1) == [Send(link, (P.Unpublish(1),))]
    s.connection_lost(link, 0.5)
    link, acts = _open(s, 1.0)
    assert [m.entity for m in _sent(acts) if type(m) is P.Publish] == [2]


def test_subscribe_sends_differences_only():
    s = _session()
    link, _ = _open(s)
    assert s.set_subscription([1, 2, 3]) == [Send(link, (P.Subscribe((1, 2, 3), ()),))]
    assert s.set_subscription([2, 3, 4]) == [Send(link, (P.Subscribe((4,), (1,)),))]
    assert s.set_subscription([4, 3, 2]) == []
    assert s.subscriptions == frozenset({2, 3, 4})
    assert s.subscribe(added=(5,), removed=(2,)) == [Send(link, (P.Subscribe((5,), (2,)),))]
    assert s.subscriptions == frozenset({3, 4, 5})


def test_backoff_doubles_to_the_cap_and_resets_after_a_welcome():
    s = _session(policy=ReconnectPolicy(0.5, 3.0))
    [c] = s.start(0.0)
    now, waits = 0.0, []
    for _ in range(5):  # five attempts that never get a WELCOME
        s.connection_lost(c.link, now, "refused")
        due = s.next_deadline(now)
        waits.append(due - now)
        assert s.timers(due - 1e-6) == []  # nothing before the deadline
        now = due
        [c] = s.timers(now)
        assert type(c) is Connect and c.address == HOME
    assert waits == [0.5, 1.0, 2.0, 3.0, 3.0]
    s.connection_made(c.link, now)
    s.receive(c.link, [WELCOME], now)
    s.connection_lost(c.link, now + 1, "reset")
    assert s.next_deadline(now + 1) == pytest.approx(now + 1.5)


def test_handshake_timeout_drops_the_attempt():
    s = _session(handshake_timeout=2.0)
    [c] = s.start(10.0)
    s.connection_made(c.link, 10.5)
    assert s.next_deadline(10.5) == 12.0
    assert s.timers(11.9) == []
    [d] = s.timers(12.0)
    assert type(d) is Drop and d.link == c.link and "WELCOME" in d.reason
    assert s.receive(c.link, [WELCOME], 12.1) == []  # late: the attempt is being dropped
    s.connection_lost(c.link, 12.2, d.reason)
    assert not s.finished and s.next_deadline(12.2) == pytest.approx(12.3)


@pytest.mark.parametrize("code", [P.ErrorCode.VERSION_MISMATCH, P.ErrorCode.TOPOLOGY_MISMATCH,
                                  P.ErrorCode.AUTH_FAILED])
def test_refusals_are_final(code):
    s = _session()
    [c] = s.start(0.0)
    s.connection_made(c.link, 0.0)
    err = P.Error(code, "no")
    assert s.receive(c.link, [err], 0.1) == [Stop(err)]
    assert s.finished and s.next_deadline(0.1) is None
    assert s.connection_lost(c.link, 0.2) == [] and s.timers(100.0) == []


def test_revoked_token_after_the_handshake_is_final():
    s = _session()
    link, _ = _open(s)
    err = P.Error(P.ErrorCode.AUTH_FAILED, "revoked")
    assert s.receive(link, [err], 1.0) == [Stop(err)]


@pytest.mark.parametrize("code", [P.ErrorCode.SERVER_FULL, P.ErrorCode.SHUTTING_DOWN, P.ErrorCode.INTERNAL,
                                  P.ErrorCode.AUTH_UNAVAILABLE])
def test_other_handshake_errors_are_retried(code):
    s = _session(policy=ReconnectPolicy(0.1, 5.0))
    [c] = s.start(0.0)
    s.connection_made(c.link, 0.0)
    [d] = s.receive(c.link, [P.Error(code, "later")], 0.1)
    assert type(d) is Drop and not s.finished
    s.connection_lost(c.link, 0.2, d.reason)
    assert s.next_deadline(0.2) == pytest.approx(0.3)


def test_throttled_login_waits_as_long_as_asked():
    s = _session(policy=ReconnectPolicy(0.1, 5.0))
    [c] = s.start(0.0)
    s.connection_made(c.link, 0.0)
    s.receive(c.link, [P.Error(P.ErrorCode.AUTH_THROTTLED, "too many failed logins; retry in 30 s")], 0.0)
    s.connection_lost(c.link, 1.0)
    assert s.next_deadline(1.0) == pytest.approx(31.0)


def test_no_reconnect_stops_on_the_first_loss():
    s = _session(policy=ReconnectPolicy(retry=False))
    link, _ = _open(s)
    assert _of(s.connection_lost(link, 1.0), Stop) == [Stop(None)]
    assert s.finished


def test_redirect_moves_the_viewer_and_its_entities():
    s = _session()
    link, _ = _open(s)
    s.subscribe((5, 6))
    s.follow(42)
    s.publish([P.Publish(1, 1, (5,), 10_000, b"x")], 0.0)
    acts = s.receive(link, [P.Redirect(2, "10.0.0.2:7401")], 1.0)
    connect = _of(acts, Connect)
    assert connect and connect[0].address == OTHER
    assert Drop(link, "nothing left to carry on this shard") in acts  # the old shard carries nothing now
    assert _of(acts, Deliver) == [Deliver(P.Redirect(2, "10.0.0.2:7401"))]
    assert s.home == OTHER and s.where(1) == OTHER and not s.connected
    assert s.connection_lost(link, 1.1) == []  # the dropped old link is not retried
    new = connect[0].link
    s.connection_made(new, 1.2)
    acts = s.receive(new, [WELCOME], 1.3)
    assert _sent(acts, new)[:3] == [P.Subscribe((5, 6), ()), P.Follow(42), P.Publish(1, 1, (5,), 8_700, b"x")]
    assert s.connected and s.set_subscription((6,)) == [Send(new, (P.Subscribe((), (5,)),))]


@dataclass(frozen=True, slots=True)
class NamedRedirect(P.Redirect):
    """A REDIRECT that names the entities to move (protocol v1's names none; a later one may)."""

    entities: tuple[int, ...] = ()


def test_redirect_naming_entities_moves_only_those():
    """Protocol v1's REDIRECT names no entities; a REDIRECT that does (a later protocol) moves just those."""

    s = _session()
    link, _ = _open(s)
    s.subscribe((5,))
    s.publish([P.Publish(1, 1, (5,), 10_000, b"a"), P.Publish(2, 1, (6,), 10_000, b"b")], 0.0)
    out = s.receive(link, [NamedRedirect(2, "10.0.0.2:7401", (2,))], 1.0)
    assert _sent(out, link) == [P.Unpublish(2)]  # the old shard forgets it now, not at expiry
    [c] = _of(out, Connect)
    assert c.address == OTHER and s.home == HOME and s.where(1) == HOME and s.where(2) == OTHER
    s.connection_made(c.link, 1.0)
    acts = s.receive(c.link, [WELCOME], 1.0)
    assert _sent(acts, c.link) == [P.Publish(2, 1, (6,), 9_000, b"b")]  # no viewer state there
    assert _of(acts, Deliver) == []  # a side link's WELCOME is not the application's business
    # new states go where the entity lives
    acts = s.publish([P.Publish(1, 2, (5,), 10_000, b"a2"), P.Publish(2, 2, (6,), 10_000, b"b2")], 2.0)
    assert _sent(acts, link) == [P.Publish(1, 2, (5,), 10_000, b"a2")]
    assert _sent(acts, c.link) == [P.Publish(2, 2, (6,), 10_000, b"b2")]
    # the last entity there leaves: the side link is closed
    acts = s.unpublish(2)
    assert acts == [Send(c.link, (P.Unpublish(2),)), Drop(c.link, "nothing left to carry on this shard")]


def test_bad_redirect_moves_nothing():
    s = _session()
    link, _ = _open(s)
    s.publish([P.Publish(1, 1, (5,), 10_000, b"a")], 0.0)
    acts = s.receive(link, [P.Redirect(2, "not an address")], 1.0)
    assert [type(a) for a in acts] == [Notice, Deliver]
    assert s.home == HOME and s.where(1) == HOME and s.connected
    assert s.receive(link, [P.Redirect(1, "127.0.0.1:7400")], 1.0) == [Deliver(P.Redirect(1, "127.0.0.1:7400"))]


def test_parse_address():
    assert parse_address("a.example:7400") == ("a.example", 7400)
    assert parse_address("[::1]:7400") == ("::1", 7400)
    assert parse_address("wss://a.example/ws") == "wss://a.example/ws"
    for bad in ("", "host", "host:0", "host:99999", ":7400", "ws://", "a b:1"):
        with pytest.raises(ValueError):
            parse_address(bad)


def test_clock_offset_from_ping_pong():
    s = _session(ping_interval=5.0)
    link, acts = _open(s, 100.0)
    [ping] = [m for m in _sent(acts) if type(m) is P.Ping]
    assert ping == P.Ping(100_000) and s.next_deadline(100.0) == 105.0
    s.receive(link, [P.Pong(100_000, 1_100_050)], 100.1)  # server is 1000 s ahead; rtt 0.1 s
    assert s.clock.offset == pytest.approx(1000.0, abs=1e-6) and s.clock.rtt == pytest.approx(0.1)
    assert s.server_time(200.0) == pytest.approx(1200.0)
    [send] = s.timers(105.0)
    assert send.msgs == (P.Ping(105_000),)
    s.receive(link, [P.Pong(105_000, 1_105_000)], 105.02)  # a faster exchange wins
    assert s.clock.offset == pytest.approx(999.99, abs=1e-6) and s.clock.rtt == pytest.approx(0.02)
    s.receive(link, [P.Pong(77, 5)], 105.1)  # a PONG for no PING of ours is ignored
    assert len(s.clock.samples) == 2


def test_time_going_backwards_moves_deadlines_and_forgets_the_clock():
    s = _session(ping_interval=5.0)
    link, _ = _open(s, 100.0)
    s.receive(link, [P.Pong(100_000, 1_100_000)], 100.0)
    assert s.clock.offset is not None
    s.publish([P.Publish(1, 1, (1,), 10_000, b"x")], 100.0)
    assert s.timers(40.0) == []  # the clock stepped back 60 s: the ping is due at 45, not at 105
    assert s.next_deadline(40.0) == pytest.approx(45.0)
    assert s.clock.offset is None  # the offset measured the old clock
    s.connection_lost(link, 41.0)
    link, acts = _open(s, 41.5)
    assert [m.validity_ms for m in _sent(acts) if type(m) is P.Publish] == [8_500]  # 1.5 s since publishing


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "1.0", None])
def test_non_finite_time_is_refused(bad):
    s = _session()
    with pytest.raises(ValueError, match="finite"):
        s.start(bad)
    assert s.start(0.0)  # nothing was lost by the refusal


def test_messages_before_welcome_drop_the_link():
    s = _session()
    [c] = s.start(0.0)
    s.connection_made(c.link, 0.0)
    [d] = s.receive(c.link, [P.Update(2**32, 1, (1,), 1000, b"x"), WELCOME], 0.1)
    assert type(d) is Drop and "expected WELCOME" in d.reason and not s.connected
    assert s.connects == 0


@pytest.mark.parametrize("bad", [WELCOME, P.Publish(1, 1, (1,), 1, b""), P.Hello(1, "", ""), P.Ping(1)])
def test_unexpected_messages_after_welcome_drop_the_link(bad):
    s = _session()
    link, _ = _open(s)
    acts = s.receive(link, [P.Leave(5), bad, P.Leave(6)], 1.0)
    assert acts[0] == Deliver(P.Leave(5)) and type(acts[1]) is Drop and len(acts) == 2  # nothing after it
    s.connection_lost(link, 1.0, acts[1].reason)
    assert not s.finished and s.next_deadline(1.0) is not None  # retried: a broken server is not final


def test_stale_link_events_are_ignored():
    s = _session()
    link, _ = _open(s)
    s.connection_lost(link, 1.0)
    [c] = s.timers(10.0)
    assert s.receive(link, [P.Leave(1)], 10.0) == []  # from the previous attempt
    assert s.connection_lost(link, 10.0) == []
    assert s.connection_made(c.link, 10.0)


def test_queries_answered_and_refusals_go_to_the_oldest():
    s = _session()
    link, _ = _open(s)
    q1, acts = s.query(P.QUERY_CELLS, [4])
    assert _sent(acts) == [P.Query(q1, P.QUERY_CELLS, (4,))]
    q2, _ = s.query(P.QUERY_IDENTITY, "bob")
    err = P.Error(P.ErrorCode.QUERY_RATE, "slow down")
    assert s.receive(link, [err], 1.0) == [Answer(q1, err), Deliver(err)]
    res = P.QueryResult(q2, ())
    assert s.receive(link, [res], 1.0) == [Answer(q2, res)]
    assert s.receive(link, [res], 1.0) == []  # answered already
    q3, _ = s.query(P.QUERY_CELLS, [1])
    s.forget_query(q3)  # timed out
    assert s.receive(link, [P.QueryResult(q3, ())], 1.0) == []


def test_bad_settings_are_refused():
    with pytest.raises(ValueError):
        ReconnectPolicy(1.0, 0.5)
    with pytest.raises(ValueError):
        ReconnectPolicy(math.nan, 1.0)
    with pytest.raises(ValueError):
        ClientSession(HOME, "d", ping_interval=0.0)


@pytest.mark.parametrize("n_cells,payload", [(0, 0), (1, 1), (64, 0), (3, 70_000), (200, 255), (15, 65_536)])
def test_publish_size_bound_is_never_below_the_encoded_size(n_cells, payload):
    from entitynet.session.batching import size_bound as _size_bound

    for big in (False, True):
        v = 2**63 - 1 if big else 1
        m = P.Publish(v, v, tuple([v] * n_cells), v, bytes(payload))
        assert _size_bound(m) >= len(P.encode_message(m))
