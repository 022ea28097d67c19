"""PVS compression by neighbour coherence: star-shaped difference clusters.

m-LOMA grows "visibility clusters" (trees of neighbouring view cells, each coded as the difference to the
cell it was reached from). We keep the idea but flatten the trees into stars: every view cell is coded as
the symmetric difference against one *root* list, never against a chain. That bounds decoding to one
`setxor` of two sorted arrays (microseconds) while keeping most of the gain, because neighbouring view
cells see nearly the same cells.

Greedy clustering in id order (layer, row, column): a view cell tries the roots of its already coded
neighbours (west, south, below) and takes the one with the smallest difference; if even that difference
exceeds `max_ratio` x its own list length, it becomes a new root (its list stored whole).

Ids are stored as uint16 when the map has fewer than 65,536 cells (else uint32).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class EncodedPvs:
    ref: np.ndarray  # (V,) int32: root index each view cell is coded against
    root_offsets: np.ndarray  # (n_roots+1,) uint32
    root_ids: np.ndarray  # sorted cell ids of each root list
    delta_offsets: np.ndarray  # (V+1,) uint32
    delta_ids: np.ndarray  # sorted symmetric difference of each view cell against its root

    def arrays(self) -> dict[str, np.ndarray]:
        return {
            "pvs_ref": self.ref,
            "pvs_root_offsets": self.root_offsets,
            "pvs_root_ids": self.root_ids,
            "pvs_delta_offsets": self.delta_offsets,
            "pvs_delta_ids": self.delta_ids,
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> EncodedPvs:
        return cls(
            arrays["pvs_ref"], arrays["pvs_root_offsets"], arrays["pvs_root_ids"],
            arrays["pvs_delta_offsets"], arrays["pvs_delta_ids"],
        )  # fmt: skip

    @property
    def nbytes(self) -> int:
        return sum(int(a.nbytes) for a in self.arrays().values())

    def decode(self, view_cell: int, n_cells: int | None = None) -> np.ndarray:
        """The sorted cell ids of one view cell: the root's list with the difference toggled.

        With `n_cells` the toggling runs on a boolean mask (a few microseconds); without it, a sorted xor."""
        r = int(self.ref[view_cell])
        root = self.root_ids[self.root_offsets[r] : self.root_offsets[r + 1]]
        d = self.delta_ids[self.delta_offsets[view_cell] : self.delta_offsets[view_cell + 1]]
        if len(d) == 0:
            return root
        if n_cells is None:
            return np.setxor1d(root, d, assume_unique=True)
        mask = np.zeros(n_cells, dtype=bool)
        mask[root] = True
        mask[d] ^= True
        return np.flatnonzero(mask)


def id_dtype(n_cells: int) -> type:
    return np.uint16 if n_cells < 65536 else np.uint32


def raw_nbytes(offsets: np.ndarray, n_cells: int) -> int:
    """Uncompressed size: every list as 2-byte (or 4-byte) ids plus a 4-byte offset per view cell."""
    width = np.dtype(id_dtype(n_cells)).itemsize
    return int(offsets[-1]) * width + 4 * len(offsets)


def encode(
    offsets: np.ndarray, ids: np.ndarray, grid_index: np.ndarray, n_cells: int, max_ratio: float = 0.35
) -> EncodedPvs:
    """Code the CSR lists (view cell v = offsets[v]:offsets[v+1] of ids) against neighbour roots."""
    V = len(offsets) - 1
    dt = id_dtype(n_cells)
    nbytes = (n_cells + 7) // 8
    bits = np.zeros((V, max(nbytes, 1)), dtype=np.uint8)
    sizes = np.diff(offsets)
    if V and n_cells:
        rowmask = np.zeros((V, n_cells), dtype=bool) if V * n_cells <= 50_000_000 else None
        if rowmask is not None:
            rowmask[np.repeat(np.arange(V), sizes), ids] = True
            bits[:, :nbytes] = np.packbits(rowmask, axis=1)
        else:
            for v in range(V):
                row = np.zeros(n_cells, bool)
                row[ids[offsets[v] : offsets[v + 1]]] = True
                bits[v, :nbytes] = np.packbits(row)
    # neighbours with smaller ids: west, south, below (grid_index is layer-major, so ids grow that way)
    nz, ny, nx = grid_index.shape
    iz, iy, ix = np.nonzero(grid_index >= 0)
    order = np.argsort(grid_index[iz, iy, ix])
    iz, iy, ix = iz[order], iy[order], ix[order]
    pad = np.full((nz + 1, ny + 1, nx + 1), -1, dtype=np.int64)
    pad[1:, 1:, 1:] = grid_index
    nbrs = np.stack(
        [pad[iz + 1, iy + 1, ix], pad[iz + 1, iy, ix + 1], pad[iz, iy + 1, ix + 1]], axis=1
    )  # (V, 3)
    root_of = np.full(V, -1, dtype=np.int64)  # the root *view cell* of each view cell
    roots: list[int] = []
    root_index: dict[int, int] = {}
    ref = np.zeros(V, dtype=np.int32)
    for v in range(V):
        cands = {int(root_of[n]) for n in nbrs[v] if n >= 0}
        best, best_cost = -1, None
        for r in cands:
            cost = int(np.bitwise_count(bits[v] ^ bits[r]).sum())
            if best_cost is None or cost < best_cost:
                best, best_cost = r, cost
        if best_cost is None or best_cost > max_ratio * sizes[v]:
            best = v
            root_index[v] = len(roots)
            roots.append(v)
        root_of[v] = best
        ref[v] = root_index[best]
    root_sizes = sizes[roots] if roots else np.zeros(0, np.int64)
    root_offsets = np.zeros(len(roots) + 1, dtype=np.uint32)
    root_offsets[1:] = np.cumsum(root_sizes)
    root_ids = (
        np.concatenate([ids[offsets[r] : offsets[r + 1]] for r in roots]).astype(dt)
        if roots
        else np.zeros(0, dt)
    )
    deltas = []
    for v in range(V):
        r = int(root_of[v])
        if r == v:
            deltas.append(np.zeros(0, dt))
            continue
        x = bits[v] ^ bits[r]
        deltas.append(np.flatnonzero(np.unpackbits(x, count=n_cells)).astype(dt))
    delta_offsets = np.zeros(V + 1, dtype=np.uint32)
    delta_offsets[1:] = np.cumsum([len(d) for d in deltas]) if V else []
    delta_ids = np.concatenate(deltas) if deltas else np.zeros(0, dt)
    return EncodedPvs(ref, root_offsets, root_ids, delta_offsets, delta_ids.astype(dt))
