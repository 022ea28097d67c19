"""The coordinator <-> worker frames: what goes out comes back, and anything else is one clear WireError."""

from __future__ import annotations

import msgpack
import pytest

from sims.workers import wire


def test_round_trip():
    data = wire.encode("out", run="r", index=1, k=3, part=0, last=True, frame=b"\x91\x00", counters={"fixes": 2},
                       step_s=0.01, owned=5)
    f = wire.decode(data)
    assert f["kind"] == "out" and f["frame"] == b"\x91\x00" and f["counters"] == {"fixes": 2}


@pytest.mark.parametrize("data, why", [
    (b"\xc1", "not a msgpack"),
    (msgpack.packb([1, 2]), "is a map"),
    (msgpack.packb({"kind": "nope"}), "unknown frame kind"),
    (msgpack.packb({"kind": "tick", "run": "r", "k": 1}), "'dead'"),
    (msgpack.packb({"kind": "tick", "run": "r", "k": "1", "dead": []}), "'k'"),
    (msgpack.packb({"kind": "tick", "run": "r", "k": True, "dead": []}), "'k'"),
    (msgpack.packb({"kind": "tick", "run": "r", "k": -1, "dead": []}), "negative tick"),
    (msgpack.packb({"kind": "tick", "run": "r", "k": 1, "dead": [-1]}), "dead worker"),
    (msgpack.packb({"kind": "tick", "run": "r", "k": 1, "dead": [], 1: 2}), "msgpack"),
    (msgpack.packb({"kind": "assign", "run": "r", "index": 2, "n": 2, "config": {}, "digests": {},
                    "timeout": 1.0, "reply": ""}), "worker 2 of 2"),
    (msgpack.packb({"kind": "out", "run": "r", "index": 0, "k": 0, "part": 0, "last": True, "frame": b"",
                    "counters": {}, "step_s": float("nan"), "owned": 0}), "step time"),
    # counters are summed by the coordinator: a string there crashed its report (int("x"))
    (msgpack.packb({"kind": "out", "run": "r", "index": 0, "k": 0, "part": 0, "last": True, "frame": b"",
                    "counters": {"fixes": "x"}, "step_s": 0.1, "owned": 0}), "counters"),
    (msgpack.packb({"kind": "bye", "run": "r", "index": 0, "counters": {"fixes": [1]}}), "counters"),
    # a worker keeps tables per worker of the run: a billion workers would not fit
    (msgpack.packb({"kind": "assign", "run": "r", "index": 0, "n": 10**9, "config": {}, "digests": {},
                    "timeout": 1.0, "reply": ""}), "at most 1024"),
])
def test_bad_frames(data, why):
    with pytest.raises(wire.WireError, match=why):
        wire.decode(data)


def test_oversized_frame_is_refused_before_parsing():
    with pytest.raises(wire.WireError, match="limit"):
        wire.decode(b"\x00" * (wire.MAX_FRAME + 1))


def test_a_sender_bug_fails_at_the_sender():
    with pytest.raises(wire.WireError):
        wire.encode("tick", run="r", k=1)
