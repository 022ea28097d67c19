"""The core's answer to a frame that is one PING, for the shell to write past the outbox (`quick_pong`), and
`written_out`, which tells it the shell wrote a client's replies itself: no quick PONG while anything is
queued (the usual frame carries both), a client before its handshake or closing gets none, and the flusher
is not woken for what went out."""

from __future__ import annotations

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from tests.entitynet.switchboard_helpers import join, make, of, pub, recv


def test_a_ready_client_with_nothing_queued_gets_its_pong_encoded():
    sb = make()
    cid = join(sb)
    got = sb.quick_pong(cid, P.Ping(1234), 5.0)
    assert got is not None
    (pong,) = P.decode_payload(P.payload_from_encoded([got]))
    assert pong == P.Pong(1234, P.now_ms(5.0))
    assert not sb.has_news() and len(sb.outbox(cid)) == 0  # nothing queued: the shell writes it


def test_no_quick_pong_before_the_handshake_nor_for_a_gone_client():
    sb = make()
    cid = sb.connect(0.0)
    assert sb.quick_pong(cid, P.Ping(1), 0.0) is None  # fed as usual: HANDSHAKE_REQUIRED
    sb.receive(cid, [P.Ping(1)], 0.0)
    assert of(recv(sb, cid), P.Error)[0].code == ErrorCode.HANDSHAKE_REQUIRED
    assert sb.quick_pong(cid, P.Ping(1), 0.0) is None  # closing
    assert sb.quick_pong(999, P.Ping(1), 0.0) is None  # no such client


def test_no_quick_pong_while_anything_is_queued_the_usual_frame_carries_both():
    sb = make()
    owner, view = join(sb), join(sb)
    sb.receive(view, [P.Subscribe((1,), ())], 0.0)
    sb.receive(owner, [pub(7, 1, (1,))], 0.0)
    assert sb.quick_pong(view, P.Ping(1), 0.0) is None  # an UPDATE is pending: one frame takes both
    sb.receive(view, [P.Ping(1)], 0.0)
    assert [type(m) for m in recv(sb, view)] == [P.Pong, P.Update]  # replies first, as always
    assert sb.quick_pong(view, P.Ping(2), 0.0) is not None  # drained: quick again


def test_written_out_clears_news_only_when_the_outbox_is_empty():
    sb = make()
    cid = join(sb)
    sb.receive(cid, [P.Ping(1)], 0.0)
    assert sb.has_news()
    sb.written_out(cid)
    assert sb.has_news()  # the PONG is still queued: it is news
    sb.outbox(cid).drain()
    sb.written_out(cid)
    assert not sb.has_news()
    sb.written_out(999)  # a client that is gone: nothing happens


def test_with_states_ok_pending_states_allow_the_pong_but_replies_and_a_close_do_not():
    sb = make()
    owner, view = join(sb), join(sb)
    sb.receive(view, [P.Subscribe((1,), ())], 0.0)
    sb.outbox(view).drain()
    sb.receive(owner, [pub(7, 1, (1,))], 0.0)
    assert sb.quick_pong(view, P.Ping(1), 0.0) is None  # the default: nothing may be pending
    got = sb.quick_pong(view, P.Ping(1), 0.0, states_ok=True)
    assert got is not None and len(sb.outbox(view)) == 1  # the UPDATE stays for the shell to take after it
    sb.receive(view, [P.Ping(2)], 0.0)  # a PONG queued: a reply must not be overtaken
    assert sb.quick_pong(view, P.Ping(3), 0.0, states_ok=True) is None
    sb.outbox(view).drain()
    sb.outbox(view).put_last_word(P.encode_message(P.Error(int(ErrorCode.SLOW_CONSUMER), "x")))  # and a close
    assert sb.quick_pong(view, P.Ping(4), 0.0, states_ok=True) is None
