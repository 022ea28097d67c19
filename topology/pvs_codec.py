"""PVS compression by neighbour coherence: difference trees of bounded depth (m-LOMA's visibility clusters).

m-LOMA grows "visibility clusters": trees of neighbouring view cells, each cell coded as the difference to the
cell it was reached from, a branch growing until the difference or the depth gets too large. We do the same
on the grid in id order (layer, row, column): a view cell takes as parent the already coded neighbour (west,
south or below) with the smallest symmetric difference, provided that neighbour is less than `max_depth`
deep; if no neighbour qualifies or the difference exceeds `max_ratio` x its own list length, it becomes a root
and stores its list whole.

Every view cell stores one sorted id array, `delta`: its symmetric difference to its parent (a root: its
list). A view cell's list is then the XOR of the deltas along its path to the root, at most `max_depth` + 1
arrays, toggled on a boolean mask: a cold decode is a few microseconds, and `PvsIndex` caches decoded lists.

Ids are stored as uint16 when the map has fewer than 65,536 cells (else uint32).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class EncodedPvs:
    """The PVS as difference trees (module docstring): per view cell a parent and a sorted delta; this
    is what the artifact stores."""
    parent: np.ndarray  # (V,) int32: the view cell this one is coded against, -1 for a root
    delta_offsets: np.ndarray  # (V+1,) uint32
    delta_ids: np.ndarray  # sorted symmetric difference to the parent (a root: its whole list)
    _parents: list | None = field(default=None, repr=False, compare=False)
    _offs: list | None = field(default=None, repr=False, compare=False)

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays under the names the artifact stores them by (in `extra`)."""
        return {"pvs_parent": self.parent, "pvs_delta_offsets": self.delta_offsets, "pvs_delta_ids": self.delta_ids}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> EncodedPvs:
        """Read back what `arrays` wrote."""
        return cls(arrays["pvs_parent"], arrays["pvs_delta_offsets"], arrays["pvs_delta_ids"])

    @property
    def nbytes(self) -> int:
        """Stored size in bytes, for the benchmark's compression figures."""
        return sum(int(a.nbytes) for a in self.arrays().values())

    @property
    def n_roots(self) -> int:
        """View cells stored whole (no parent): fewer means neighbours compress better."""
        return int((self.parent < 0).sum())

    def decode(self, view_cell: int, n_cells: int | None = None) -> np.ndarray:
        """The sorted cell ids of one view cell: the XOR of the deltas on its path to the root."""
        if self._parents is None:  # Python lists: the chain walk is scalar work
            self._parents = self.parent.tolist()
            self._offs = self.delta_offsets.tolist()
        parents, offs, ids = self._parents, self._offs, self.delta_ids
        v = int(view_cell)
        parts = [ids[offs[v] : offs[v + 1]]]
        v = parents[v]
        while v >= 0:
            parts.append(ids[offs[v] : offs[v + 1]])
            v = parents[v]
        if len(parts) == 1:
            return parts[0]
        # an id is in the list iff it occurs an odd number of times along the chain
        counts = np.bincount(np.concatenate(parts), minlength=n_cells or 0)
        return np.flatnonzero(counts & 1)


def id_dtype(n_cells: int) -> type:
    """The narrowest id type for `n_cells` cells: uint16 below 65,536, which halves a city map's PVS."""
    return np.uint16 if n_cells < 65536 else np.uint32


def raw_nbytes(offsets: np.ndarray, n_cells: int) -> int:
    """Uncompressed size: every list as 2-byte (or 4-byte) ids plus a 4-byte offset per view cell."""
    width = np.dtype(id_dtype(n_cells)).itemsize
    return int(offsets[-1]) * width + 4 * len(offsets)


def encode(
    offsets: np.ndarray,
    ids: np.ndarray,
    grid_index: np.ndarray,
    n_cells: int,
    max_ratio: float = 0.5,
    max_depth: int = 8,
) -> EncodedPvs:
    """Code the CSR lists (view cell v = ids[offsets[v]:offsets[v+1]]) as difference trees."""
    V = len(offsets) - 1
    dt = id_dtype(n_cells)
    nbytes = max((n_cells + 7) // 8, 1)
    sizes = np.diff(offsets)
    bits = np.zeros((V, nbytes), dtype=np.uint8)
    for c0 in range(0, V, 4096):  # bitmaps in blocks to bound memory
        sl = slice(c0, min(V, c0 + 4096))
        rows = np.zeros((sl.stop - sl.start, n_cells), dtype=bool)
        lo, hi = offsets[sl.start], offsets[sl.stop]
        rows[np.repeat(np.arange(sl.stop - sl.start), sizes[sl]), ids[lo:hi]] = True
        if n_cells:
            bits[sl, : (n_cells + 7) // 8] = np.packbits(rows, axis=1)
    # already coded neighbours: west, south, below (grid_index is layer-major, ids grow that way)
    nz, ny, nx = grid_index.shape
    iz, iy, ix = np.nonzero(grid_index >= 0)
    order = np.argsort(grid_index[iz, iy, ix])
    iz, iy, ix = iz[order], iy[order], ix[order]
    pad = np.full((nz + 1, ny + 1, nx + 1), -1, dtype=np.int64)
    pad[1:, 1:, 1:] = grid_index
    nbrs = np.stack([pad[iz + 1, iy + 1, ix], pad[iz + 1, iy, ix + 1], pad[iz, iy + 1, ix + 1]], axis=1)
    parent = np.full(V, -1, dtype=np.int32)
    depth = np.zeros(V, dtype=np.int64)
    deltas: list[np.ndarray] = []
    for v in range(V):
        best, best_cost = -1, None
        for u in nbrs[v]:
            if u < 0 or depth[u] >= max_depth:
                continue
            cost = int(np.bitwise_count(bits[v] ^ bits[u]).sum())
            if best_cost is None or cost < best_cost:
                best, best_cost = int(u), cost
        if best_cost is None or best_cost > max_ratio * sizes[v]:
            deltas.append(ids[offsets[v] : offsets[v + 1]].astype(dt))
            continue
        parent[v] = best
        depth[v] = depth[best] + 1
        deltas.append(np.flatnonzero(np.unpackbits(bits[v] ^ bits[best], count=n_cells)).astype(dt))
    delta_offsets = np.zeros(V + 1, dtype=np.uint32)
    if V:
        delta_offsets[1:] = np.cumsum([len(d) for d in deltas])
    delta_ids = np.concatenate(deltas).astype(dt) if deltas else np.zeros(0, dt)
    return EncodedPvs(parent, delta_offsets, delta_ids)


@dataclass
class StarPvs:
    """The first layout (artifacts built before the difference trees): each view cell coded against one root
    list. Read-only, kept so that artifacts already built and cached stay usable."""

    ref: np.ndarray
    root_offsets: np.ndarray
    root_ids: np.ndarray
    delta_offsets: np.ndarray
    delta_ids: np.ndarray

    def decode(self, view_cell: int, n_cells: int | None = None) -> np.ndarray:
        """The sorted cell ids of one view cell: its root's list XOR its delta."""
        r = int(self.ref[view_cell])
        root = self.root_ids[self.root_offsets[r] : self.root_offsets[r + 1]]
        d = self.delta_ids[self.delta_offsets[view_cell] : self.delta_offsets[view_cell + 1]]
        if len(d) == 0:
            return root
        return np.setxor1d(root, d, assume_unique=True)


def codec_from_arrays(arrays: dict[str, np.ndarray]) -> EncodedPvs | StarPvs:
    """The codec of an artifact's `extra` arrays, whichever layout it was written with."""
    if "pvs_parent" in arrays:
        return EncodedPvs.from_arrays(arrays)
    if "pvs_root_ids" in arrays:
        return StarPvs(arrays["pvs_ref"], arrays["pvs_root_offsets"], arrays["pvs_root_ids"],
                       arrays["pvs_delta_offsets"], arrays["pvs_delta_ids"])  # fmt: skip
    raise ValueError("the topology's PVS arrays are incomplete (no pvs_parent)")
