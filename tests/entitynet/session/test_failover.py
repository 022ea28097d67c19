"""The client session's failover to the cluster's other shards (issue 13): a shard that keeps failing hands
everything the session carried there (its entities, and the viewer when it is home) to the next alternate."""

from __future__ import annotations

import pytest

from entitynet import protocol as P
from entitynet.session import ClientSession, Connect, ReconnectPolicy, Send

HOME = ("127.0.0.1", 7400)
OTHER = ("127.0.0.1", 7401)
THIRD = ("127.0.0.1", 7402)
WELCOME = P.Welcome(1, 1, 0)


def _connects(actions):
    return [a for a in actions if type(a) is Connect]


def _sent(actions, link):
    return [m for a in actions if type(a) is Send and a.link == link for m in a.msgs]


def _open(s, link, now):
    s.connection_made(link, now)
    return s.receive(link, [WELCOME], now)


def test_a_dead_home_shard_moves_the_entities_and_the_viewer_to_an_alternate():
    s = ClientSession(HOME, "d", policy=ReconnectPolicy(0.01, 0.02), alternates=(OTHER, THIRD), failover_s=1.5,
                      failover_attempts=0)  # by time only
    (c,) = _connects(s.start(0.0))
    _open(s, c.link, 0.0)
    s.publish([P.Publish(1, 1, (5,), 10_000, b"x")], 0.0)
    s.subscribe((7, 8))
    out = s.connection_lost(c.link, 1.0, "reset")
    assert not _connects(out) and s.home == HOME  # the first failure: retry the same shard
    (c2,) = _connects(s.timers(2.0))
    assert c2.address == HOME
    out = s.connection_lost(c2.link, 2.1, "refused")  # failing for 1.1 s < failover_s
    assert not _connects(out)
    (c2,) = _connects(s.timers(2.3))
    out = s.connection_lost(c2.link, 2.6, "refused")  # failing for 1.6 s: fail over
    (c3,) = _connects(out)
    assert c3.address == OTHER and s.home == OTHER and s.where(1) == OTHER
    replay = _sent(_open(s, c3.link, 2.7), c3.link)
    assert P.Subscribe((7, 8), ()) in replay
    (p,) = [m for m in replay if isinstance(m, P.Publish)]
    assert p.entity == 1 and p.validity_ms <= 10_000 - 2700  # shortened by the time since it was published


def test_without_alternates_the_session_keeps_retrying_its_shard():
    s = ClientSession(HOME, "d", policy=ReconnectPolicy(0.01, 0.02))
    (c,) = _connects(s.start(0.0))
    for i in range(4):
        s.connection_lost(c.link, 1.0 + i, "refused")
        (c,) = _connects(s.timers(2.0 + i))
        assert c.address == HOME and s.home == HOME


def test_redirects_teach_the_session_the_cluster():
    s = ClientSession(HOME, "d", policy=ReconnectPolicy(0.01, 0.02), failover_s=1.0, failover_attempts=0)
    (c,) = _connects(s.start(0.0))
    _open(s, c.link, 0.0)
    s.publish([P.Publish(1, 1, (5,), 10_000, b"x")], 0.0)
    out = s.receive(c.link, [P.Redirect(1, "127.0.0.1:7401")], 0.5)
    (c2,) = _connects(out)
    assert c2.address == OTHER and set(s.alternates) == {HOME, OTHER}
    _open(s, c2.link, 0.6)
    s.connection_lost(c2.link, 1.0, "reset")
    (c3,) = _connects(s.timers(2.0))
    out = s.connection_lost(c3.link, 2.1, "reset")
    (c4,) = _connects(out)  # failing since 1.0: 1.1 s >= failover_s
    assert c4.address == HOME and s.where(1) == HOME  # back to the shard it learned first


def test_a_lost_link_whose_redial_is_refused_fails_over_at_once():
    """A SIGKILLed shard refuses the first redial: the session moves then (the default two attempts), not after
    `failover_s` of retrying a shard that is gone; the survivors hold its first PUBLISH until they have decided."""
    s = ClientSession(HOME, "d", policy=ReconnectPolicy(0.05, 0.5), alternates=(OTHER, THIRD), failover_s=30.0)
    (c,) = _connects(s.start(0.0))
    _open(s, c.link, 0.0)
    s.publish([P.Publish(1, 1, (5,), 10_000, b"x")], 0.0)
    s.subscribe((7,))
    out = s.connection_lost(c.link, 1.0, "reset")
    assert not _connects(out) and s.home == HOME  # one redial of the same shard first: a blip costs nothing
    (c2,) = _connects(s.timers(1.05))
    assert c2.address == HOME
    (c3,) = _connects(s.connection_lost(c2.link, 1.06, "refused"))
    assert c3.address == OTHER and s.home == OTHER and s.where(1) == OTHER  # 0.06 s after the loss, not 30 s
    replay = _sent(_open(s, c3.link, 1.07), c3.link)
    assert P.Subscribe((7,), ()) in replay and [m.entity for m in replay if isinstance(m, P.Publish)] == [1]


def test_failover_attempts_must_not_be_negative():
    with pytest.raises(ValueError, match="failover_attempts"):
        ClientSession(HOME, "d", failover_attempts=-1)
