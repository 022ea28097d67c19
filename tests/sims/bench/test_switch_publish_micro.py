"""The per-PUBLISH micro-benchmark: every path it times queues the same bytes (its `same_bytes` would say
otherwise), and it reports a figure per path. Timings themselves are not checked here (benchmarks do that)."""

from __future__ import annotations

import math

from entitynet.switchboard import outbox
from sims.bench import switch_publish_micro as M


def test_every_path_queues_the_same_bytes_and_is_timed():
    was = outbox.compiled_in_use()
    res = M.measure(rounds=1, n_entities=300, n_frames=20, per_frame=50, n_cells=40, n_viewers=6,
                    cells_per_viewer=12)
    assert outbox.compiled_in_use() == was  # the path in use is put back
    assert res["same_bytes"]
    expected = {"pure"} | ({"route", "run"} if outbox.COMPILED is not None else set())
    assert set(res["medians"]) == expected
    assert all(math.isfinite(v) and v >= 0 for v in res["medians"].values())
    assert res["publishes_timed"] == 1000


def test_the_workload_moves_entities_and_keeps_seqs_increasing():
    frames = M._workload(50, 10, 20, 30, seed=3)
    msgs = [m for f in frames for m in f]
    assert len(msgs) == 50 + 200
    last: dict[int, int] = {}
    moved = 0
    for m in msgs:
        assert m.seq == last.get(m.entity, 0) + 1
        last[m.entity] = m.seq
        assert len(set(m.cells)) == len(m.cells) and all(0 <= c < 30 for c in m.cells)
    cells: dict[int, tuple] = {}
    for m in msgs:
        moved += m.entity in cells and cells[m.entity] != m.cells
        cells[m.entity] = m.cells
    assert 20 <= moved <= 120  # about 30 % of the 200 updates move
