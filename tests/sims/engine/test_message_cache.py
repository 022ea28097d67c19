"""The viewers' shared frame decoder (issue 23): the same messages as the codec, the same errors for bad
frames, each distinct message decoded once and shared, and bounded."""

from __future__ import annotations

import random

import msgpack
import pytest

from entitynet import protocol as P
from sims.engine import message_cache
from sims.engine.message_cache import MessageCache


@pytest.fixture(params=["compiled", "python"])
def make_cache(request):
    """MessageCache with the walk in C (sims/engine/_frame_walk.pyx) or the Python walk, the reference."""
    if request.param == "compiled" and message_cache._COMPILED is None:
        pytest.skip("sims/engine/_frame_walk.pyx was not built (no C compiler)")

    def make(*a, **kw) -> MessageCache:
        cache = MessageCache(*a, **kw)
        if request.param == "python":
            cache._walk = None
        assert (cache._walk is not None) == (request.param == "compiled")
        return cache
    return make


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


def test_the_same_messages_as_the_codec_each_distinct_one_decoded_once_and_shared(make_cache):
    msgs, payload = _frame()
    cache = make_cache()
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


def test_bad_frames_get_the_codecs_error_and_the_cache_keeps_working(make_cache):
    msgs, payload = _frame(12, seed=3)
    cache = make_cache()
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


def test_frames_over_the_limits_are_refused_as_the_codec_refuses_them(make_cache):
    small = P.CodecLimits(max_frame=64, max_messages=3)
    _, payload = _frame(4)
    cache = make_cache(small)
    assert _cached(cache, payload) == _codec(payload, small) == ("error", P.ErrorCode.FRAME_TOO_LARGE)
    four_leaves = P.encode_payload([P.Leave(i) for i in range(4)])
    assert _cached(cache, four_leaves) == _codec(four_leaves, small) == ("error", P.ErrorCode.FRAME_TOO_LARGE)


def test_it_is_bounded(make_cache):
    cache = make_cache(max_entries=5)
    for i in range(12):
        cache.decode(P.encode_payload([P.Leave(i)]))
        assert len(cache) <= 5
    with pytest.raises(ValueError):
        make_cache(max_entries=0)


def test_a_frame_with_several_bad_messages_gets_the_codecs_error_not_the_first_messages(make_cache):
    # the codec unpacks the whole frame before it checks any message, so a later message that msgpack refuses
    # (an extension type, a string that is not UTF-8) decides the error over an earlier message's bad field
    ext = msgpack.packb([11, 1, 2, [1], 5, msgpack.ExtType(1, b"x"), None])
    frames = [
        P.array_header(2) + msgpack.packb([99]) + ext,  # unknown type, then an extension type
        P.array_header(2) + msgpack.packb([99]) + b"\x91\xa1\xff",  # unknown type, then bad UTF-8
        P.array_header(2) + msgpack.packb([11, -1, 2, [1], 5, b"x", None]) + ext,  # bad field, then extension
    ]
    cache = make_cache()
    for data in frames:
        want = _codec(data)
        assert want == ("error", P.ErrorCode.MALFORMED)
        assert _cached(cache, data) == want, data
        assert _cached(cache, data) == want, data


def _random_object(rng: random.Random, depth: int = 0):
    """A msgpack value of any of the format's families and widths (nested up to three deep)."""
    kind = rng.randrange(12 if depth < 3 else 9)
    if kind == 0:
        return rng.choice([0, 1, 127, 128, 255, 256, 65535, 65536, 2**32 - 1, 2**32, 2**64 - 1])
    if kind == 1:
        return rng.choice([-1, -32, -33, -128, -129, -32768, -32769, -2**31, -2**31 - 1, -2**63])
    if kind == 2:
        return rng.choice([None, True, False])
    if kind == 3:
        return rng.random() * 1e6
    if kind == 4:
        return "é" * rng.choice([0, 1, 15, 16, 40, 200, 40_000])  # fixstr, str 8, 16 and 32
    if kind == 5:
        return rng.randbytes(rng.choice([0, 1, 255, 256, 70_000]))  # bin 8, 16, 32
    if kind == 6:
        return msgpack.ExtType(rng.randrange(128), rng.randbytes(rng.choice([1, 2, 4, 8, 16, 3, 300, 70_000])))
    if kind in (7, 8):
        return rng.randrange(-(2**15), 2**15)
    if kind in (9, 10):
        return [_random_object(rng, depth + 1) for _ in range(rng.choice([0, 1, 15, 16, 20]))]
    return {rng.randrange(1000): _random_object(rng, depth + 1) for _ in range(rng.choice([0, 1, 15, 16, 20]))}


def _pieces_by_msgpack(payload: bytes):
    """Each element's bytes by msgpack's own unpacker (`skip`, `tell`), or None where it refuses the frame."""
    up = msgpack.Unpacker(max_buffer_size=len(payload) + 1)
    up.feed(payload)
    try:
        n = up.read_array_header()
        out, at = [], up.tell()
        for _ in range(n):
            up.skip()
            out.append(payload[at:up.tell()])
            at = up.tell()
    except Exception:
        return None
    return out if at == len(payload) else None


def test_the_compiled_walk_finds_msgpacks_own_boundaries_for_every_kind_of_value():
    if message_cache._COMPILED is None:
        pytest.skip("sims/engine/_frame_walk.pyx was not built (no C compiler)")
    pieces = MessageCache(max_entries=10**9)
    pieces._decode_new = lambda piece, size: piece  # (every message new: its bytes, as the walk cut them)

    def walk(data: bytes, max_messages: int, out: list):
        return message_cache._COMPILED.walk(data, pieces, max_messages, out)

    rng = random.Random(7)
    for trial in range(400):
        n = rng.choice([0, 1, 3, 15, 16, 40])
        payload = P.array_header(n) + b"".join(msgpack.packb(_random_object(rng), use_bin_type=True)
                                               for _ in range(n))
        variants = [payload]
        if trial % 2 and len(payload) > 1:
            variants += [payload[: rng.randrange(1, len(payload))], payload + b"\x00"]
            b = bytearray(payload)
            b[rng.randrange(len(b))] = rng.choice([0xC1, 0xDD, 0xDF, 0xC6, 0xDB, rng.randrange(256)])
            variants.append(bytes(b))
        for data in variants:
            got: list = []
            res = walk(data, 1_000_000, got)
            want = _pieces_by_msgpack(data)
            if want is None:
                assert res is None, data[:40]
            else:
                assert res is not None and got == want and res[0] == len(want), data[:40]
    # a frame's header counts more messages than it holds; an absurd length inside a message; an empty frame
    assert walk(b"\xdd\xff\xff\xff\xff\x90", 10**12, []) is None
    assert walk(b"\x91\xdb\xff\xff\xff\xff", 10, []) is None
    assert walk(b"", 10, []) is None
    assert walk(b"\x90", 10, []) == (0, 1)


def test_messages_are_kept_across_clears_within_their_generations(make_cache):
    msgs, payload = _frame(8, seed=4)
    told: list = []
    cache = make_cache(on_new=told.append)
    first = cache.decode(payload)
    assert cache.decoded == len(msgs) and told == msgs
    cache.clear()  # the next tick: the same stored UPDATEs reach a viewer that subscribed to their cells
    again = cache.decode(payload)
    assert again == msgs and all(a is b for a, b in zip(first, again, strict=True))
    assert cache.decoded == len(msgs) and cache.misses == 2 * len(msgs)  # looked up, not decoded again
    assert told == msgs + msgs  # still told once per tick, as before the keeping
    assert [cache.size(m) for m in again] == [len(P.encode_message(m)) for m in msgs]
    # without keeping, every message after a clear is the codec's again
    plain = make_cache(keep=0)
    plain.decode(payload)
    plain.clear()
    assert plain.decode(payload) == msgs and plain.decoded == 2 * len(msgs)


def test_the_kept_messages_are_bounded_in_count_and_in_clears(make_cache):
    cache = make_cache(keep=3, keep_clears=2)
    for i in range(10):
        cache.decode(P.encode_payload([P.Leave(i)]))
        assert len(cache._kept) + len(cache._kept_old) <= 6
    cache.clear()
    assert cache.decode(P.encode_payload([P.Leave(0)])) == [P.Leave(0)] and cache.decoded == 11  # long gone
    cache.decode(P.encode_payload([P.Leave(9)]))
    assert cache.decoded == 11  # kept
    for _ in range(4):  # two generations of two clears each
        cache.clear()
    cache.decode(P.encode_payload([P.Leave(9)]))
    assert cache.decoded == 12
    with pytest.raises(ValueError):
        make_cache(keep=-1)
    with pytest.raises(ValueError):
        make_cache(keep_clears=0)


def test_both_walks_keep_and_count_alike_through_generations_and_clears():
    if message_cache._COMPILED is None:
        pytest.skip("sims/engine/_frame_walk.pyx was not built (no C compiler)")
    rng = random.Random(11)
    pool = [P.Leave(i) for i in range(40)] + _frame(40, seed=12)[0]
    told: dict[str, list] = {"compiled": [], "python": []}
    caches = {w: MessageCache(max_entries=25, keep=7, keep_clears=3, on_new=told[w].append) for w in told}
    caches["python"]._walk = None
    for step in range(300):
        frame = P.encode_payload(rng.sample(pool, rng.randint(1, 12)))
        got = {w: c.decode(frame) for w, c in caches.items()}
        assert got["compiled"] == got["python"] == P.decode_payload(frame)
        if rng.random() < 0.2:
            for c in caches.values():
                c.clear()
        a, b = caches["compiled"], caches["python"]
        assert (a.hits, a.misses, a.decoded, a._clears) == (b.hits, b.misses, b.decoded, b._clears), step
        assert (list(a._kept), list(a._kept_old), list(a._messages)) == \
            (list(b._kept), list(b._kept_old), list(b._messages)), step
    assert told["compiled"] == told["python"]
