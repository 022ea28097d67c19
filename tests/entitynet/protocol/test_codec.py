"""Protocol v1 codec: round trips, framing, limits, and fuzzing (only ProtocolError on any bytes)."""

from __future__ import annotations

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet import protocol as P

ids = st.integers(0, P.MAX_INT)
cells = st.lists(st.integers(0, P.MAX_CELL), max_size=8, unique=True).map(tuple)
text = st.text(max_size=40)
payload = st.binary(max_size=100)
updates = st.builds(P.Update, ids, ids, cells, st.integers(0, P.MAX_VALIDITY_MS), payload, st.none() | text)

messages = st.one_of(
    st.builds(P.Hello, st.integers(0, 0xFFFF), text, text),
    st.builds(P.Welcome, st.integers(0, 0xFFFF), ids, ids, st.dictionaries(text, ids, max_size=4)),
    st.builds(P.Error, st.integers(0, 999), text),
    st.builds(P.Publish, ids, ids, cells, st.integers(0, P.MAX_VALIDITY_MS), payload),
    st.builds(P.Unpublish, ids),
    st.builds(P.Subscribe, cells, cells),
    st.builds(P.Follow, ids),
    st.builds(P.Unfollow, ids),
    st.builds(P.Query, ids, st.just(P.QUERY_IDENTITY), text),
    st.builds(P.Query, ids, st.just(P.QUERY_CELLS), cells),
    st.builds(P.QueryResult, ids, st.lists(updates, max_size=3).map(tuple)),
    updates,
    st.builds(P.Leave, ids),
    st.builds(P.Redirect, ids, text),
    st.builds(P.Privacy, st.none() | text, st.none() | st.lists(text, max_size=4).map(tuple)),
    st.builds(P.Ping, ids),
    st.builds(P.Pong, ids, ids),
    st.builds(P.Camera, *[st.floats(-P.MAX_COORD, P.MAX_COORD, allow_nan=False)] * 3),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(messages, max_size=6))
def test_round_trip(msgs):
    assert P.decode_payload(P.encode_payload(msgs)) == msgs


@settings(max_examples=100, deadline=None)
@given(st.lists(messages, min_size=1, max_size=4), st.lists(st.integers(1, 50), max_size=10))
def test_frame_decoder_reassembles_any_split(msgs, cuts):
    data = P.encode_frame(msgs) * 2
    dec = P.FrameDecoder()
    out = []
    pos = 0
    for c in cuts + [len(data)]:
        dec.receive_data(data[pos : pos + c])
        pos += c
        while (got := dec.next_messages()) is not None:
            out.append(got)
    assert out == [msgs, msgs]
    assert not dec.mid_frame


def test_payload_from_encoded_matches_encode_payload():
    msgs = [P.Leave(i) for i in range(20)] + [P.Update(1, 2, (3,), 4, b"x", None)] * 70000
    enc = [P.encode_message(m) for m in msgs]
    lim = P.CodecLimits(max_messages=100_000, max_frame=1 << 24)
    assert P.decode_payload(P.payload_from_encoded(enc), lim) == msgs


@settings(max_examples=1000, deadline=None)
@given(st.binary(max_size=200))
def test_fuzz_payload_raises_only_protocol_error(data):
    try:
        P.decode_payload(data)
    except P.ProtocolError:
        pass


structured = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=5)
    | st.binary(max_size=5),
    lambda ch: st.lists(ch, max_size=6) | st.dictionaries(st.text(max_size=3), ch, max_size=3),
    max_leaves=8,
)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.integers(1, 16) | st.integers(-2, 20), min_size=1, max_size=1).flatmap(
    lambda t: st.lists(structured, max_size=7).map(lambda rest: [t[0], *rest])), st.integers(1, 3))
def test_fuzz_well_formed_msgpack_with_wrong_fields(msg, n):
    data = msgpack.packb([msg] * n, use_bin_type=True)
    try:
        P.decode_payload(data)
    except P.ProtocolError:
        pass


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=300))
def test_fuzz_frame_decoder(data):
    dec = P.FrameDecoder(P.CodecLimits(max_frame=1000))
    dec.receive_data(data)
    try:
        while dec.next_messages() is not None:
            pass
    except P.ProtocolError:
        pass
    assert dec.buffered <= len(data)


def test_four_gigabyte_prefix_refused_immediately():
    dec = P.FrameDecoder()
    dec.receive_data(b"\xff\xff\xff\xff")
    with pytest.raises(P.ProtocolError) as ei:
        dec.next_payload()
    assert ei.value.code == P.ErrorCode.FRAME_TOO_LARGE


def test_truncated_frame_waits():
    data = P.encode_frame([P.Ping(5)])
    dec = P.FrameDecoder()
    dec.receive_data(data[:-1])
    assert dec.next_messages() is None and dec.mid_frame
    dec.receive_data(data[-1:])
    assert dec.next_messages() == [P.Ping(5)]


@pytest.mark.parametrize(
    ("obj", "code"),
    [
        ([[99, 1]], P.ErrorCode.UNKNOWN_TYPE),
        ([[P.PUBLISH, 1, 1, [1, 1], 10, b""]], P.ErrorCode.BAD_FIELD),  # duplicate cells
        ([[P.PUBLISH, 1, 1, [1], -1, b""]], P.ErrorCode.BAD_FIELD),
        ([[P.PUBLISH, 1, 1, [1], 10, "str"]], P.ErrorCode.BAD_FIELD),
        ([[P.PUBLISH, 1, 1, [1], 10, b"x" * 5000]], P.ErrorCode.BAD_FIELD),
        ([[P.PUBLISH, 1, 1, list(range(65)), 10, b""]], P.ErrorCode.BAD_FIELD),
        ([[P.PUBLISH, True, 1, [1], 10, b""]], P.ErrorCode.BAD_FIELD),
        ([[P.SUBSCRIBE, [1.5], []]], P.ErrorCode.BAD_FIELD),
        ([[P.SUBSCRIBE, [2**31], []]], P.ErrorCode.BAD_FIELD),
        ([[P.PING]], P.ErrorCode.BAD_FIELD),
        ([[P.QUERY, 1, "nope", 1]], P.ErrorCode.BAD_FIELD),
        ({"a": 1}, P.ErrorCode.MALFORMED),
        ([[]], P.ErrorCode.MALFORMED),
        ([["x"]], P.ErrorCode.MALFORMED),
    ],
)
def test_bad_messages_have_codes(obj, code):
    with pytest.raises(P.ProtocolError) as ei:
        P.decode_payload(msgpack.packb(obj, use_bin_type=True))
    assert ei.value.code == code


def test_extension_types_and_trailing_bytes_rejected():
    with pytest.raises(P.ProtocolError):
        P.decode_payload(msgpack.packb([[P.PING, msgpack.ExtType(5, b"x")]]))
    with pytest.raises(P.ProtocolError):
        P.decode_payload(P.encode_payload([P.Ping(1)]) + b"\x00")


def test_frame_size_limit():
    lim = P.CodecLimits(max_frame=100)
    with pytest.raises(P.ProtocolError) as ei:
        P.decode_payload(P.encode_payload([P.Ping(1)] * 100), lim)
    assert ei.value.code == P.ErrorCode.FRAME_TOO_LARGE
