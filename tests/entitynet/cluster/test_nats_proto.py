"""The sans-IO NATS codec: byte-exact encoding, parsing in any slicing, bounds on hostile input."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from entitynet.cluster import nats_proto as N


def test_encoding_is_the_documented_text_protocol():
    assert N.pub("en.c.5", b"hi") == b"PUB en.c.5 2\r\nhi\r\n"
    assert N.pub("en.snap", b"", reply="_INBOX.x.1") == b"PUB en.snap _INBOX.x.1 0\r\n\r\n"
    assert N.sub("en.c.*", 7) == b"SUB en.c.* 7\r\n"
    assert N.sub("q", 3, queue="workers") == b"SUB q workers 3\r\n"
    assert N.unsub(7) == b"UNSUB 7\r\n" and N.unsub(7, 2) == b"UNSUB 7 2\r\n"
    assert N.connect({"echo": False}) == b'CONNECT {"echo":false}\r\n'


@pytest.mark.parametrize("bad", ["", "a b", "a..b", "a.", "a\r\nPUB x 1", "x" * 300])
def test_bad_subjects_are_refused(bad):
    with pytest.raises(N.NatsProtocolError):
        N.sub(bad, 1)


def test_wildcards_only_where_allowed():
    assert N.check_subject("a.*.c", wildcards=True)
    with pytest.raises(N.NatsProtocolError):
        N.check_subject("a.*", wildcards=False)


STREAM = (b'INFO {"server_id":"x","max_payload":1048576}\r\n+OK\r\nPING\r\nPONG\r\n'
          b"MSG en.c.1 3 5\r\nhello\r\nMSG en.snap 4 _INBOX.a.1 3\r\n\r\nX\r\n-ERR 'Unknown Protocol Operation'\r\n")
EXPECTED = [N.Info({"server_id": "x", "max_payload": 1048576}), N.Ok(), N.Ping(), N.Pong(),
            N.Msg("en.c.1", 3, None, b"hello"), N.Msg("en.snap", 4, "_INBOX.a.1", b"\r\nX"),
            N.Err("Unknown Protocol Operation")]


def _parse_all(chunks):
    p = N.Parser()
    out = []
    for c in chunks:
        p.receive_data(c)
        while (ev := p.next_event()) is not None:
            out.append(ev)
    return out, p


def test_parses_every_operation():
    out, p = _parse_all([STREAM])
    assert out == EXPECTED and p.buffered == 0


@given(st.lists(st.integers(1, len(STREAM) - 1), max_size=20))
def test_any_slicing_gives_the_same_events(cuts):
    cuts = sorted(set(cuts))
    chunks = [STREAM[a:b] for a, b in zip([0, *cuts], [*cuts, len(STREAM)], strict=True)]
    out, _ = _parse_all(chunks)
    assert out == EXPECTED


def test_hostile_input_raises_protocol_errors_only():
    for bad in (b"NOPE\r\n", b"MSG a 1\r\n", b"MSG a x 3\r\nabc\r\n", b"INFO [1]\r\n", b"INFO {\r\n",
                b"MSG a 1 3\r\nabcXY", b"MSG a 1 99999999999\r\n"):
        p = N.Parser(max_payload=1024)
        p.receive_data(bad)
        with pytest.raises(N.NatsProtocolError):
            while p.next_event() is not None:
                pass
    p = N.Parser(max_control_line=64)
    p.receive_data(b"X" * 100)
    with pytest.raises(N.NatsProtocolError, match="control line"):
        p.next_event()


@given(st.binary(max_size=200))
def test_fuzz_never_raises_anything_else(data):
    p = N.Parser(max_payload=100)
    p.receive_data(data)
    try:
        while p.next_event() is not None:
            pass
    except N.NatsProtocolError:
        pass
