"""The compiled message loop (`entitynet/protocol/_decode.pyx`, built by pip: PUBLISH and SUBSCRIBE in C) decodes
exactly what the Python reference decodes and raises the same errors, on good and on hostile input.

Why: the compiled loop is an optimisation of the server's busiest decoding, never a second behaviour: a client
that sends a malformed PUBLISH, NaN, an oversized cell list or a cell that does not exist must get the same
numbered ERROR with the same text whichever path the server was built with.
"""

from __future__ import annotations

import math
import random

import msgpack
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet import protocol as P
from entitynet.protocol import codec

pytestmark = pytest.mark.skipif(codec._COMPILED is None, reason="the compiled decoder was not built")


def _outcome(data: bytes, limits: P.CodecLimits, compiled: bool):
    was = codec._decode_messages is not None
    codec.use_compiled_decoder(compiled)
    try:
        return ("ok", P.decode_payload(data, limits))
    except P.ProtocolError as err:
        return ("error", err.code, err.text)
    finally:
        codec.use_compiled_decoder(was)


def _same(data: bytes, limits: P.CodecLimits = P.DEFAULT_LIMITS):
    pure = _outcome(data, limits, False)
    fast = _outcome(data, limits, True)
    assert fast == pure
    if pure[0] == "ok":  # equal and of the same types, field by field (equality alone takes 1 == True)
        for a, b in zip(pure[1], fast[1], strict=True):
            assert type(a) is type(b)
            if type(a) is P.Publish:
                assert [type(getattr(a, f)) for f in a.__slots__] == [type(getattr(b, f)) for f in b.__slots__]
                assert hash(a) == hash(b)
    return pure


def _raw(*msgs) -> bytes:
    return msgpack.packb(list(msgs), use_bin_type=True)


GOOD = [P.PUBLISH, 7, 3, [1, 2, 9], 1000, b"model"]

HOSTILE = {
    "too few fields": [P.PUBLISH, 7, 3, [1], 1000],
    "too many fields": [*GOOD, None],
    "entity negative": [P.PUBLISH, -1, 3, [1], 1000, b""],
    "entity past MAX_INT": [P.PUBLISH, P.MAX_INT + 1, 3, [1], 1000, b""],
    "entity past 64 bits": [P.PUBLISH, 2**64 - 1, 3, [1], 1000, b""],
    "entity NaN": [P.PUBLISH, math.nan, 3, [1], 1000, b""],
    "entity a bool": [P.PUBLISH, True, 3, [1], 1000, b""],
    "entity a string": [P.PUBLISH, "7", 3, [1], 1000, b""],
    "seq NaN": [P.PUBLISH, 7, math.nan, [1], 1000, b""],
    "seq infinite": [P.PUBLISH, 7, math.inf, [1], 1000, b""],
    "seq negative": [P.PUBLISH, 7, -3, [1], 1000, b""],
    "cells not an array": [P.PUBLISH, 7, 3, 5, 1000, b""],
    "cells a map": [P.PUBLISH, 7, 3, {1: 2}, 1000, b""],
    "cell NaN": [P.PUBLISH, 7, 3, [1, math.nan], 1000, b""],
    "cell a float": [P.PUBLISH, 7, 3, [1.0], 1000, b""],
    "cell negative": [P.PUBLISH, 7, 3, [4, -1], 1000, b""],
    "cell past MAX_CELL": [P.PUBLISH, 7, 3, [P.MAX_CELL + 1], 1000, b""],
    "cell past 64 bits": [P.PUBLISH, 7, 3, [2**64 - 1], 1000, b""],
    "cell nil": [P.PUBLISH, 7, 3, [None], 1000, b""],
    "cells repeated": [P.PUBLISH, 7, 3, [5, 6, 5], 1000, b""],
    "oversized cell list": [P.PUBLISH, 7, 3, list(range(65)), 1000, b""],
    "huge cell list": [P.PUBLISH, 7, 3, list(range(5000)), 1000, b""],
    "validity NaN": [P.PUBLISH, 7, 3, [1], math.nan, b""],
    "validity past a day": [P.PUBLISH, 7, 3, [1], P.MAX_VALIDITY_MS + 1, b""],
    "payload a string": [P.PUBLISH, 7, 3, [1], 1000, "model"],
    "payload oversized": [P.PUBLISH, 7, 3, [1], 1000, bytes(2049)],
    "payload nil": [P.PUBLISH, 7, 3, [1], 1000, None],
    "type a bool": [True, 7, 3, [1], 1000, b""],
    "type a float": [4.0, 7, 3, [1], 1000, b""],
    "type unknown with six fields": [99, 7, 3, [1], 1000, b""],
    "type past 64 bits": [2**64 - 1, 7, 3, [1], 1000, b""],
}


SUBSCRIBE_HOSTILE = {
    "too few fields": [P.SUBSCRIBE, [1]],
    "too many fields": [P.SUBSCRIBE, [1], [], []],
    "added not an array": [P.SUBSCRIBE, 5, []],
    "removed nil": [P.SUBSCRIBE, [1], None],
    "cell NaN": [P.SUBSCRIBE, [1, math.nan], []],
    "cell negative": [P.SUBSCRIBE, [], [-1]],
    "cell past MAX_CELL": [P.SUBSCRIBE, [P.MAX_CELL + 1], []],
    "cell past 64 bits": [P.SUBSCRIBE, [], [2**64 - 1]],
    "cell a bool": [P.SUBSCRIBE, [True], []],
    "oversized cell list": [P.SUBSCRIBE, list(range(65_537)), []],
}


def test_good_publishes_decode_alike():
    got = _same(_raw(GOOD, [P.PUBLISH, 0, 0, [], 0, b""], [P.PUBLISH, P.MAX_INT, P.MAX_INT, [0, P.MAX_CELL],
                                                          P.MAX_VALIDITY_MS, bytes(2048)]))
    assert got[1][0] == P.Publish(7, 3, (1, 2, 9), 1000, b"model")
    assert got[1][2].cells == (0, P.MAX_CELL)


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_hostile_publish_gives_the_same_error(name):
    got = _same(_raw(GOOD, HOSTILE[name], GOOD))  # a good message before and after: the bad one decides
    assert got[0] == "error"


@pytest.mark.parametrize("name", sorted(SUBSCRIBE_HOSTILE))
def test_hostile_subscribe_gives_the_same_error(name):
    got = _same(_raw([P.SUBSCRIBE, [1], [2]], SUBSCRIBE_HOSTILE[name], GOOD))
    assert got[0] == "error"


def test_big_subscribes_decode_alike():
    got = _same(_raw([P.SUBSCRIBE, list(range(65_536)), [0, P.MAX_CELL, 0]], [P.SUBSCRIBE, [], []]))
    assert got[1] == [P.Subscribe(tuple(range(65_536)), (0, P.MAX_CELL, 0)), P.Subscribe()]
    assert _same(_raw([P.SUBSCRIBE, [1, 2, 3], []]), P.CodecLimits(max_subscribe_cells=2))[0] == "error"


def test_cell_lists_past_the_compiled_bound_take_the_reference_path():
    wide = P.CodecLimits(max_publish_cells=200)
    got = _same(_raw([P.PUBLISH, 7, 3, list(range(100)), 1000, b""]), wide)
    assert got[1][0].cells == tuple(range(100))
    tight = P.CodecLimits(max_publish_cells=2)
    assert _same(_raw([P.PUBLISH, 7, 3, [1, 2, 3], 1000, b""]), tight)[0] == "error"
    assert _same(_raw([P.PUBLISH, 7, 3, [1, 2], 1000, bytes(11)]), P.CodecLimits(max_payload=10))[0] == "error"


def test_other_messages_in_the_same_frame_decode_alike():
    msgs = [P.Ping(5), P.Publish(1, 2, (3,), 4, b"x"), P.Subscribe((1, 2), ()), P.Publish(9, 9, (), 9, b""),
            P.Unpublish(1), P.Camera(1.0, 2.0, 3.0)]
    assert _same(P.encode_payload(msgs)) == ("ok", msgs)


@settings(max_examples=300)
@given(st.lists(st.one_of(
    st.integers(-2, 2**64 - 1), st.floats(allow_nan=True), st.none(), st.booleans(), st.binary(max_size=8),
    st.text(max_size=3), st.lists(st.one_of(st.integers(-2, 2**33), st.floats(), st.none()), max_size=70)),
    min_size=5, max_size=5))
def test_any_six_field_publish_decodes_alike(fields):
    _same(_raw(GOOD, [P.PUBLISH, *fields]))


def test_mutated_frames_decode_alike():
    rng = random.Random(25)
    msgs: list[P.Message] = [P.Publish(e, e + 1, (e, e + 3), 500, bytes(e)) for e in range(20)]
    msgs += [P.Subscribe((1, 2, 300), (4,)), P.Ping(3)]
    base = bytearray(P.encode_payload(msgs))
    for _ in range(2000):
        data = bytearray(base)
        for _ in range(rng.randrange(1, 4)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        _same(bytes(data))
