"""The viewers' shared frame decoder (issue 23): the same messages as the codec, the same errors for bad
frames, each distinct message decoded once and shared, and bounded."""

from __future__ import annotations

import random

import msgpack
import pytest

from entitynet import protocol as P
from sims.engine.message_cache import MessageCache


def _frame(n: int = 8, seed: int = 1) -> tuple[list[P.Message], bytes]:
    rng = random.Random(seed)
    msgs: list[P.Message] = []
    for i in range(n):
        if i % 4 == 3:
            msgs.append(P.Leave(i))
        else:
            cells = tuple(rng.sample(range(500), rng.randint(0, 6)))
            msgs.append(P.Update(i, rng.randint(0, 99), cells, rng.randint(0, 60_000), rng.randbytes(40),
                                 None if i % 2 else "alice"))
    return msgs, P.encode_payload(msgs)


def _codec(payload: bytes, limits=P.DEFAULT_LIMITS):
    try:
        return P.decode_payload(payload, limits)
    except P.ProtocolError as exc:
        return ("error", exc.code)


def _cached(cache: MessageCache, payload: bytes):
    try:
        return cache.decode(payload)
    except P.ProtocolError as exc:
        return ("error", exc.code)


def test_the_same_messages_as_the_codec_each_distinct_one_decoded_once_and_shared():
    msgs, payload = _frame()
    cache = MessageCache()
    first = cache.decode(payload)
    assert first == msgs == P.decode_payload(payload)
    again = cache.decode(payload)  # another viewer's copy of the same frame
    assert all(a is b for a, b in zip(first, again, strict=True))
    assert (cache.misses, cache.hits) == (len(msgs), len(msgs))
    # a frame holding some of the same messages among new ones shares those
    more = [P.Leave(99), *msgs[:3]]
    got = cache.decode(P.encode_payload(more))
    assert got == more and got[1] is first[0]
    assert [cache.size(m) for m in got] == [len(P.encode_message(m)) for m in more]
    assert cache.size(P.Leave(99)) is None  # an equal message it did not return: no size
    cache.clear()
    assert len(cache) == 0 and cache.size(got[0]) is None


def test_bad_frames_get_the_codecs_error_and_the_cache_keeps_working():
    msgs, payload = _frame(12, seed=3)
    cache = MessageCache()
    bad = [
        b"", b"\x91", b"\xc1", payload + b"\x01", payload[:-1], msgpack.packb({"a": 1}), msgpack.packb(7),
        msgpack.packb([[11, 1, 2, [1], 5, b"x"]]),  # an UPDATE with a field missing
        msgpack.packb([[11, -1, 2, [1], 5, b"x", None]]),  # a negative entity id
        msgpack.packb([[11, 1, 2, [1], 5, msgpack.ExtType(1, b"x"), None]]),  # an extension type
        msgpack.packb([[99]]), msgpack.packb([[]]), msgpack.packb(["x"]),
        P.array_header(P.DEFAULT_LIMITS.max_messages + 1) + b"\x90" * (P.DEFAULT_LIMITS.max_messages + 1),
    ]
    rng = random.Random(5)
    for _ in range(300):  # bytes changed, cut or added anywhere
        b = bytearray(payload)
        for _k in range(rng.randint(1, 3)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        bad.append(bytes(b[: rng.randint(1, len(b))]) if rng.random() < 0.3 else bytes(b))
    for data in bad:
        want = _codec(data)
        assert _cached(cache, data) == want, data
        assert _cached(cache, data) == want, data  # and again, from the table where it was decoded
    assert cache.decode(payload) == msgs  # nothing lost for the next good frame


def test_frames_over_the_limits_are_refused_as_the_codec_refuses_them():
    small = P.CodecLimits(max_frame=64, max_messages=3)
    _, payload = _frame(4)
    cache = MessageCache(small)
    assert _cached(cache, payload) == _codec(payload, small) == ("error", P.ErrorCode.FRAME_TOO_LARGE)
    four_leaves = P.encode_payload([P.Leave(i) for i in range(4)])
    assert _cached(cache, four_leaves) == _codec(four_leaves, small) == ("error", P.ErrorCode.FRAME_TOO_LARGE)


def test_it_is_bounded():
    cache = MessageCache(max_entries=5)
    for i in range(12):
        cache.decode(P.encode_payload([P.Leave(i)]))
        assert len(cache) <= 5
    with pytest.raises(ValueError):
        MessageCache(max_entries=0)


def test_a_frame_with_several_bad_messages_gets_the_codecs_error_not_the_first_messages():
    # the codec unpacks the whole frame before it checks any message, so a later message that msgpack refuses
    # (an extension type, a string that is not UTF-8) decides the error over an earlier message's bad field
    ext = msgpack.packb([11, 1, 2, [1], 5, msgpack.ExtType(1, b"x"), None])
    frames = [
        P.array_header(2) + msgpack.packb([99]) + ext,  # unknown type, then an extension type
        P.array_header(2) + msgpack.packb([99]) + b"\x91\xa1\xff",  # unknown type, then bad UTF-8
        P.array_header(2) + msgpack.packb([11, -1, 2, [1], 5, b"x", None]) + ext,  # bad field, then extension
    ]
    cache = MessageCache()
    for data in frames:
        want = _codec(data)
        assert want == ("error", P.ErrorCode.MALFORMED)
        assert _cached(cache, data) == want, data
        assert _cached(cache, data) == want, data
