"""The compiled fan-out loops (`_fanout.pyx`, built by pip) do exactly what the pure-Python reference does, and
the switchboard forwards the same bytes with either.

Why: the compiled path is an optimisation of three loops, never a second behaviour; the reference stays the
fallback where no compiler was at hand. `fanout_path` runs a test once per path (the compiled one is skipped,
saying so, where it was not built; tests/conftest.py).
"""

from __future__ import annotations

import random

import pytest

from entitynet import protocol as P
from entitynet.switchboard import outbox
from tests.entitynet.switchboard_helpers import join, make, pub, recv


def _random_case(seed: int):
    rng = random.Random(seed)
    states = {v: {rng.randrange(50): b"old"} for v in range(40)}
    cids = set(rng.sample(range(40), 25))
    return states, cids, rng.randrange(50)


@pytest.mark.skipif(outbox.COMPILED is None, reason="the compiled fan-out was not built")
def test_compiled_loops_match_the_reference():
    c = outbox.COMPILED
    for seed in range(20):
        for fn in ("fan_out", "fan_out_open", "fan_out_to"):
            a, cids, e = _random_case(seed)
            b, _, _ = _random_case(seed)
            if fn == "fan_out":
                outbox.fan_out_py(a, cids, e, b"new")
                c.fan_out(b, cids, e, b"new")
            elif fn == "fan_out_open":
                gone = cids | {97, 98}  # ids of clients that are gone: skipped
                outbox.fan_out_open_py(a, gone, e, b"new")
                c.fan_out_open(b, gone, e, b"new")
            else:
                outbox.fan_out_to_py(tuple(a[v] for v in cids), e, b"new")
                c.fan_out_to(tuple(b[v] for v in cids), e, b"new")
            assert a == b and [list(x) for x in a.values()] == [list(x) for x in b.values()]  # order too
    with pytest.raises(KeyError):
        c.fan_out({}, {1}, 5, b"x")  # a missing client is an error, as in the reference
    with pytest.raises(TypeError):
        c.fan_out_to([{}], 5, b"x")  # the handle is a tuple


def _scenario() -> list[list[tuple]]:
    """Viewers on overlapping cells, entities that stay and move: what each viewer receives, in order."""
    sb = make()
    viewers = [join(sb) for _ in range(6)]
    for k, v in enumerate(viewers):
        sb.receive(v, [P.Subscribe((k % 3, 3), ())], 0.0)
        recv(sb, v)
    owner = join(sb)
    out = []
    for seq in range(1, 8):
        sb.receive(owner, [pub(1, seq, (3,)), pub(2, seq, (seq % 3,)), pub(3, seq, (1, 2))], seq * 0.1)
        if seq % 2:
            out.append([[(type(m).__name__, getattr(m, "seq", None)) for m in recv(sb, v)] for v in viewers])
    return out


def test_forwarding_is_the_same_on_both_paths(fanout_path):
    got = _scenario()
    outbox.use_compiled(False)
    want = _scenario()  # the reference
    assert got == want
    assert any(("Leave", None) in frame for step in want for frame in step)  # the scenario has LEAVEs ...
    assert sum(len(frame) for step in want for frame in step) > 30  # ... and plenty of UPDATEs


@pytest.mark.skipif(outbox.COMPILED is None or not hasattr(outbox.COMPILED, "take_states"),
                    reason="the compiled take_states was not built")
def test_compiled_take_states_matches_the_reference():
    """Same answer and same outbox afterwards, over the cases that refuse (replies, a close, overflow, too many,
    too large) and those that take; the compiled one is what `use_compiled` installs as the method."""
    rng = random.Random(5)
    for _ in range(300):
        boxes = [outbox.Outbox(50, 5) for _ in range(2)]
        n = rng.randrange(0, 12)
        sizes = [rng.randrange(1, 40) for _ in range(n)]
        extra = rng.choice(["", "control", "close", "overflow"])
        for ob in boxes:
            for k, s in enumerate(sizes):
                ob.put_state(k * 7, bytes([k]) * s)
            if extra == "control":
                ob.put_control(b"c")
            elif extra == "close":
                ob.put_last_word(b"e")
            elif extra == "overflow":
                for _ in range(7):
                    ob.put_control(b"c")
        args = (rng.randrange(1, 14), rng.randrange(0, 12), rng.randrange(0, 300))
        want = outbox.Outbox.take_states_py(boxes[0], *args)
        got = outbox.COMPILED.take_states(boxes[1], *args)
        assert got == want and boxes[0].drain() == boxes[1].drain()
    was = outbox.compiled_in_use()
    try:
        outbox.use_compiled(True)
        assert outbox.Outbox.take_states is outbox.COMPILED.take_states
        outbox.use_compiled(False)
        assert outbox.Outbox.take_states is outbox.Outbox.take_states_py
    finally:
        outbox.use_compiled(was)


class _Attrs:
    """An instance whose `__dict__` is a split-table dict (keys shared with the class's other instances)."""

    def __init__(self) -> None:
        self.a = b"a"
        self.b = b"b"


def _dict_shapes() -> list[dict]:
    """Dicts of every shape the compiled store's prefetch reads (it looks into dict internals to find the index
    slot and the entry ahead of each store): empty, small, with 1-, 2- and 4-byte index tables, with deleted
    entries, keyed by str (another entry layout), mixed keys, and a split-table instance dict."""
    big = {k: b"v" for k in range(50_000)}  # over 2**15 slots: 4-byte indices
    holes = {k: b"v" for k in range(300)}
    for k in range(0, 300, 3):
        del holes[k]
    return [{}, {7: b"x"}, {k: b"v" for k in range(100)}, {k * 1024: b"v" for k in range(200)}, big, holes,
            {"s" + str(k): b"v" for k in range(20)}, {1: b"v", "one": b"v", (1, 2): b"v", 2.5: b"v"},
            _Attrs().__dict__]


@pytest.mark.skipif(outbox.COMPILED is None, reason="the compiled fan-out was not built")
@pytest.mark.parametrize("key", [0, 1, 5, 1023, 1024, 49_999, 50_000, -1, -2, 2**61 - 1, 2**61, 2**64 + 3, -(2**70)])
def test_compiled_store_with_prefetch_matches_the_reference_on_every_dict_shape(key):
    shapes_a, shapes_b = _dict_shapes(), _dict_shapes()
    many_a = tuple(shapes_a * 5)  # longer than every prefetch distance, each dict met several times
    many_b = tuple(shapes_b * 5)
    outbox.fan_out_to_py(many_a, key, b"new")
    outbox.COMPILED.fan_out_to(many_b, key, b"new")
    for a, b in zip(shapes_a, shapes_b, strict=True):
        assert a == b and list(a) == list(b)
    for n in range(0, 20):  # every length around the prefetch distances
        a = tuple({k: b"o" for k in range(n)} for _ in range(n))
        b = tuple({k: b"o" for k in range(n)} for _ in range(n))
        outbox.fan_out_to_py(a, key, b"n")
        outbox.COMPILED.fan_out_to(b, key, b"n")
        assert a == b
