"""`ClientSession.delivers_whole`: a shell may hand a frame on whole only where `receive` would do nothing but
deliver each of its messages (the simulation's viewer fleet, sims/engine/viewer_fleet.py)."""

from __future__ import annotations

from entitynet import protocol as P


def test_a_session_hands_on_whole_only_frames_it_would_only_deliver():
    from entitynet.session.session import ClientSession

    s = ClientSession(("127.0.0.1", 1), "d", "")
    (connect,) = [a for a in s.start(0.0) if type(a).__name__ == "Connect"]
    s.connection_made(connect.link, 0.0)
    upd = P.Update(1, 1, (1,), 1000, b"x")
    assert not s.delivers_whole(connect.link, [upd], 0.1)  # still in the handshake
    s.receive(connect.link, [P.Welcome(P.PROTOCOL_VERSION, 1, {})], 0.2)
    assert s.delivers_whole(connect.link, [upd, P.Leave(1)], 0.3)
    assert s.delivers_whole(connect.link, [], 0.3)
    assert not s.delivers_whole(connect.link, [upd, P.Pong(1, 2)], 0.3)
    assert not s.delivers_whole(connect.link + 1, [upd], 0.3)  # not a live link
