"""The HELLO checks (order, failed-login back-off) and re-checking tokens after a revocation, sans-IO."""

from __future__ import annotations

import pytest

from entitynet import protocol as P
from entitynet.switchboard.access import revalidate
from entitynet.switchboard.ratelimit import FailureThrottle
from tests.entitynet.switchboard_helpers import join, make, pub, recv


def _hello(sb, token, peer="10.0.0.1", now=0.0, digest=None):
    cid = sb.connect(now, peer=peer)
    sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, token, sb.config.digest if digest is None else digest)], now)
    return cid, recv(sb, cid)


def _authed(**kw):
    users = {"tok-a": "alice", "tok-b": "bob"}
    return make(open_mode=False, authenticate=lambda t: users.get(t), **kw), users


def test_throttle_backs_off_exponentially_per_key():
    t = FailureThrottle(free=2, base=1.0, cap=8.0)
    assert [t.failed("x", 0.0) for _ in range(2)] == [0.0, 0.0]
    assert t.retry_after("x", 0.0) == 0.0
    assert t.failed("x", 0.0) == 1.0 and t.retry_after("x", 0.5) == 0.5
    assert t.failed("x", 1.0) == 2.0 and t.failed("x", 3.0) == 4.0
    assert t.failed("x", 7.0) == 8.0 and t.failed("x", 15.0) == 8.0  # capped
    assert t.retry_after("y", 15.0) == 0.0  # other peers are not affected
    assert t.retry_after("x", 23.0) == 0.0
    assert t.failed("x", 23.0) == 8.0  # still remembered after the block ended ...
    assert t.failed("x", 31.0 + 80.1) == 0.0  # ... until 10 * cap quiet seconds pass


def test_throttle_remembers_bounded_number_of_peers():
    t = FailureThrottle(free=0, base=1.0, cap=1.0, max_peers=100)
    for i in range(1000):
        t.failed(f"p{i}", 0.0)
    assert len(t) == 100 and t.retry_after("p999", 0.5) > 0
    with pytest.raises(ValueError):
        FailureThrottle(base=0.0)


def test_wrong_tokens_throttled_per_peer_without_checking_the_token():
    sb, _ = _authed(auth_fail_free=2, auth_fail_base_s=10.0, auth_fail_cap_s=60.0)
    for now in (0.0, 0.1):
        assert [m.code for m in _hello(sb, "guess", now=now)[1]] == [P.ErrorCode.AUTH_FAILED]
    (err,) = _hello(sb, "guess", now=0.2)[1]  # third failure: blocked for 10 s from now
    assert err.code == P.ErrorCode.AUTH_FAILED and "10 s" in err.text
    (err,) = _hello(sb, "tok-a", now=5.0)[1]  # even a valid token: the token is not looked at
    assert err.code == P.ErrorCode.AUTH_THROTTLED and "retry in 6 s" in err.text
    assert err.code in P.FATAL_ERRORS
    assert isinstance(_hello(sb, "tok-a", peer="10.0.0.2", now=5.0)[1][0], P.Welcome)  # other peers: fine
    assert isinstance(_hello(sb, "tok-a", now=10.3)[1][0], P.Welcome)  # after the block
    (err,) = _hello(sb, "guess", now=10.4)[1]  # the count was not reset: the next block doubles
    assert "20 s" in err.text
    assert sb.errors[int(P.ErrorCode.AUTH_THROTTLED)] == 1


def test_digest_checked_only_after_auth():
    """An unauthenticated client learns nothing about the server's map, not even its digest."""
    sb, _ = _authed()
    (err,) = _hello(sb, "wrong", digest="other-digest")[1]
    assert err.code == P.ErrorCode.AUTH_FAILED and sb.config.digest not in err.text
    (err,) = _hello(sb, "tok-a", digest="other-digest")[1]
    assert err.code == P.ErrorCode.TOPOLOGY_MISMATCH and sb.config.digest[:16] in err.text


def test_revalidate_closes_connections_of_revoked_tokens():
    sb, users = _authed()
    alice, bob = join(sb, "tok-a"), join(sb, "tok-b")
    sb.receive(bob, [P.Subscribe((1,), ())], 0)
    sb.receive(alice, [pub(1, 1, (1,))], 0)
    assert isinstance(recv(sb, bob)[0], P.Update)
    assert revalidate(sb, users.get) == []
    del users["tok-a"]
    assert revalidate(sb, users.get) == [alice]
    (err,) = recv(sb, alice)
    assert err.code == P.ErrorCode.AUTH_FAILED and "revoked" in err.text
    assert isinstance(recv(sb, bob)[0], P.Leave)  # its entities are gone
    assert revalidate(sb, users.get) == []  # closed once
    users["tok-b"] = "mallory"  # a token that now names someone else is no longer bob's
    assert revalidate(sb, users.get) == [bob]


def test_open_mode_is_not_revalidated():
    sb = make()
    join(sb, "alice")
    assert revalidate(sb, lambda t: None) == []
