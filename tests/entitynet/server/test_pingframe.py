"""`lone_ping_ms` (entitynet.server.pingframe) against the reference deframer and decoder: it never accepts what
they would not decode to exactly one PING, and it reads every PING frame our encoder writes."""

from __future__ import annotations

import struct

import msgpack
from hypothesis import given
from hypothesis import strategies as st

from entitynet import protocol as P
from entitynet.server.pingframe import lone_ping_ms


def reference(data: bytes) -> int | None:
    """client_ms if the reference reads `data` as exactly one whole frame holding one PING, else None."""
    dec = P.FrameDecoder(P.DEFAULT_LIMITS)
    dec.receive_data(data)
    try:
        msgs = dec.next_messages()
    except P.ProtocolError:
        return None
    if msgs is None or dec.mid_frame or len(msgs) != 1 or type(msgs[0]) is not P.Ping:
        return None
    return msgs[0].client_ms


EDGES = [0, 1, 127, 128, 255, 256, 65_535, 65_536, 2**32 - 1, 2**32, P.MAX_INT - 1, P.MAX_INT]


def test_every_ping_our_encoder_writes_is_read_alike():
    for ms in EDGES + [1_764_000_000_000, 12_345]:
        data = P.encode_frame([P.Ping(ms)])
        assert lone_ping_ms(data) == reference(data) == ms


def test_hostile_near_misses_fall_back():
    ping = P.encode_frame([P.Ping(300)])
    over = struct.pack(">I", 12) + b"\x91\x92\x0f\xcf" + (P.MAX_INT + 1).to_bytes(8, "big")
    signed = struct.pack(">I", 6) + b"\x91\x92\x0f\xd1\x01\x2c"  # 300 as int16: valid, but not canonical
    cases = [b"", ping[:-1], ping + ping, ping + b"\x00", over, signed,
             struct.pack(">I", 4) + b"\x91\x92\x0f\xc3",  # true: a bool, refused by the codec
             struct.pack(">I", 4) + b"\x91\x92\x0f\xff",  # -1
             struct.pack(">I", 5) + b"\x91\x92\x0f\x01",  # length prefix says more than there is
             P.encode_frame([P.Pong(1, 2)]), P.encode_frame([P.Ping(1), P.Ping(2)])]
    for data in cases:
        assert lone_ping_ms(data) is None, data
    assert reference(signed) == 300  # the reference still takes it: the shell falls back to it
    assert reference(over) is None  # above 2**53 with a right length: the codec refuses it, and so must the recogniser


@given(st.binary(max_size=20))
def test_arbitrary_bytes_never_disagree(data):
    ms = lone_ping_ms(data)
    assert ms is None or ms == reference(data)


@given(st.integers(min_value=-(2**63), max_value=2**64 - 1), st.binary(max_size=3))
def test_any_msgpack_integer_with_any_tail(v, tail):
    payload = msgpack.packb([[15, v]]) + tail
    data = struct.pack(">I", len(payload)) + payload
    ms = lone_ping_ms(data)
    assert ms is None or ms == reference(data)
    if not tail and 0 <= v <= P.MAX_INT:
        assert ms == v
