"""PVS compression: lossless for any lists, smaller for coherent neighbours."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from topology.pvs_codec import EncodedPvs, encode, raw_nbytes


def csr(lists):
    offsets = np.zeros(len(lists) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([len(x) for x in lists])
    ids = np.concatenate([np.asarray(x, dtype=np.int32) for x in lists]) if lists else np.zeros(0, np.int32)
    return offsets, ids


def grid_index(nz, ny, nx, holes=()):
    index = np.full((nz, ny, nx), -1, dtype=np.int32)
    keep = np.ones((nz, ny, nx), bool)
    for h in holes:
        keep[h] = False
    index[keep] = np.arange(int(keep.sum()))
    return index


@settings(max_examples=40, deadline=None)
@given(
    st.integers(1, 3), st.integers(1, 4), st.integers(1, 4), st.integers(1, 300), st.randoms(use_true_random=False)
)
def test_round_trip_any_lists(nz, ny, nx, n_cells, rnd):
    index = grid_index(nz, ny, nx)
    V = int((index >= 0).sum())
    lists = [sorted(rnd.sample(range(n_cells), rnd.randint(0, n_cells))) for _ in range(V)]
    offsets, ids = csr(lists)
    enc = encode(offsets, ids, index, n_cells)
    again = EncodedPvs.from_arrays(enc.arrays())
    for v in range(V):
        assert again.decode(v).tolist() == lists[v]
        assert again.decode(v, n_cells).tolist() == lists[v]


def test_coherent_neighbours_compress_and_holes_are_fine():
    rng = np.random.default_rng(0)
    index = grid_index(3, 10, 10, holes=[(0, 4, 4), (0, 4, 5), (1, 4, 4)])
    V = int((index >= 0).sum())
    n_cells = 2000
    base = rng.random(n_cells) < 0.3
    lists = []
    for _ in range(V):
        row = base.copy()
        flip = rng.integers(0, n_cells, 10)
        row[flip] = ~row[flip]
        lists.append(np.flatnonzero(row))
    offsets, ids = csr(lists)
    enc = encode(offsets, ids, index, n_cells)
    for v in range(V):
        assert enc.decode(v).tolist() == lists[v].tolist()
    assert enc.nbytes < raw_nbytes(offsets, n_cells) / 4
    assert enc.delta_ids.dtype == np.uint16
    assert enc.n_roots < V / 4


def test_large_maps_use_wide_ids():
    index = grid_index(1, 1, 2)
    offsets, ids = csr([[0, 70000], [70000]])
    enc = encode(offsets, ids, index, 70001)
    assert enc.delta_ids.dtype == np.uint32
    assert enc.decode(0).tolist() == [0, 70000] and enc.decode(1).tolist() == [70000]


def test_depth_is_bounded():
    index = grid_index(1, 1, 50)
    lists = [list(range(100 + k)) for k in range(50)]  # each differs from its west neighbour by one id
    offsets, ids = csr(lists)
    enc = encode(offsets, ids, index, 200, max_depth=3)
    for v in range(50):
        d, u = 0, v
        while enc.parent[u] >= 0:
            u, d = int(enc.parent[u]), d + 1
        assert d <= 3
        assert enc.decode(v, 200).tolist() == lists[v]
    assert enc.n_roots == 13  # a new root every 4 cells


def test_empty_lists():
    index = grid_index(1, 2, 2)
    offsets, ids = csr([[], [], [], []])
    enc = encode(offsets, ids, index, 5)
    assert all(enc.decode(v).tolist() == [] for v in range(4))


def test_reads_both_layouts():
    from topology.pvs_codec import StarPvs, codec_from_arrays

    index = grid_index(1, 1, 3)
    offsets, ids = csr([[1, 2, 3], [1, 2], [5]])
    enc = codec_from_arrays(encode(offsets, ids, index, 6).arrays())
    assert [enc.decode(v, 6).tolist() for v in range(3)] == [[1, 2, 3], [1, 2], [5]]
    star = {  # the first layout: roots [1, 2, 3] and [5]; view cell 1 toggles 3
        "pvs_ref": np.array([0, 0, 1], np.int32), "pvs_root_offsets": np.array([0, 3, 4], np.uint32),
        "pvs_root_ids": np.array([1, 2, 3, 5], np.uint16), "pvs_delta_offsets": np.array([0, 0, 1, 1], np.uint32),
        "pvs_delta_ids": np.array([3], np.uint16),
    }  # fmt: skip
    old = codec_from_arrays(star)
    assert isinstance(old, StarPvs)
    assert [old.decode(v).tolist() for v in range(3)] == [[1, 2, 3], [1, 2], [5]]
