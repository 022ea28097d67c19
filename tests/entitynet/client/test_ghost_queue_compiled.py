"""The ghost table's per-message step compiled (`_ghost_queue.pyx`, issue 23) against the pure reference
(`ghost_table.queue_messages`): two tables fed the same hostile streams (out-of-order seqs, LEAVEs of unknown
entities, validity 0, undecodable payloads, the same message object to many viewers, a pair twice in one frame,
compaction on the way) end with the same arrays, queue, counts and ghosts, bit for bit; and bad frames are
refused alike, before anything is taken."""

import math
import random

import numpy as np
import pytest

from entitynet.client import WorldModel, encode, ghost_table
from entitynet.client.ghost_table import GhostTable
from entitynet.protocol import Leave, Update
from tests.entitynet.client.test_ghost_table import _stream

compiled = pytest.importorskip("entitynet.client._ghost_queue", reason="the compiled queue is not built here")


class _Table(GhostTable):
    """A table whose per-message step is `step` (the reference or the compiled one)."""

    def __init__(self, step) -> None:
        super().__init__(None)
        self._step = step

    def receive(self, col, msgs, now, decoded=False):
        saved, ghost_table._queue = ghost_table._queue, self._step
        try:
            return super().receive(col, msgs, now, decoded)
        finally:
            ghost_table._queue = saved


def _state(t: GhostTable) -> tuple:
    k = len(t.vmsg) - len(t._pending)
    return (t.held[:t.n_rows, :t.n_cols].tobytes(), t.bad[:t.n_cols].tobytes(), t.vseq[:k].tobytes(),
            t.vexp[:k].tobytes(), t.vrow[:k].tobytes(), t.vok[:k].tobytes(), t.vmid[:k].tobytes(),
            t.voff[:k + 1].tobytes(), t.vcells[:int(t.voff[k])].tobytes(), list(t._q_col), list(t._q_ver),
            sorted(t._q_pairs), list(t._pending), [id(m) for m in t.vmsg], sorted(t._row_of.items()))


@pytest.mark.parametrize("seed", range(6))
def test_compiled_and_reference_steps_leave_the_same_table(seed):
    rng = random.Random(seed)
    ref, comp = _Table(ghost_table.queue_messages), _Table(compiled.queue_messages)
    for t in (ref, comp):
        for _ in range(5):
            t.add_viewer()
        if seed % 2:
            t._compact_at = 8  # compact often: versions dropped, rows reused, this `now`'s versions remapped
    frame: list = []
    for step, (v, msg, now) in enumerate(_stream(rng, 1200)):
        frame.append(msg)
        if rng.random() < 0.3:  # frames of 1-6 messages, the same entity twice in some
            decoded = rng.random() < 0.5
            leaves = [t.receive(v, list(frame), now, decoded) for t in (ref, comp)]
            assert leaves[0] == leaves[1]
            frame = []
        if step % 41 == 0:
            assert _state(ref) == _state(comp)
            if step % 82 == 0:
                for t in (ref, comp):
                    t.flush()
    for t in (ref, comp):
        t.flush()
    assert _state(ref) == _state(comp)
    assert ref.bad.sum() > 0 and (ref.held >= 0).any()


@pytest.mark.parametrize("step", ["reference", "compiled"])
def test_bad_frames_are_refused_whole_by_either_step(step):
    t = _Table(ghost_table.queue_messages if step == "reference" else compiled.queue_messages)
    col = t.add_viewer()
    p = encode(WorldModel(0.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1))
    t.receive(col, [Update(1, 1, (1,), 5000, p)], 0.0)
    before = _state(t)
    for bad in ([Update(2, 1, (1,), 5000, p), Update(3, 1, (float("nan"),), 5000, p)],
                [Update(2, 1, (1,), 5000, p), Update(3, 1, (2**64,), 5000, p)],
                [Update(2, 1, (1,), 5000, p), Update(3, -2**64, (1,), 5000, p)],
                [Update(2, 1, (1,), 5000, p), Leave(math.inf)],
                [Leave(1), "LEAVE"]):
        with pytest.raises((ValueError, TypeError)):
            t.receive(col, bad, 1.0)
        assert _state(t) == before
    assert t.receive(col, [], 1.0) == 0 and _state(t) == before
    rows, vers = t.rows_of(col)
    assert t.entity(rows).tolist() == [1] and np.array_equal(t.vseq[vers], [1])
