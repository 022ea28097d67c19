"""Run-time PVS lookup: position -> view cell -> the visibility cells it may see (numpy only).

Why apart from the builder (`topology.pvs`): the builder needs shapely and multiprocessing; clients, viewers
and servers only read the artifact's grid and compressed lists, and must not load either.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from topology.viewgrid import ViewGrid

if TYPE_CHECKING:
    from topology.pvs import PvsResult


class PvsIndex:
    """Position -> view cell -> PVS, in microseconds (pure arithmetic plus one cached decode).

    Positions outside the grid are *clamped* to the nearest grid cell: x and y to the edge columns, z below
    the ground to the lowest layer and z above `max_height` to the top layer (whose PVS then
    under-approximates a higher camera's view). A position inside a view cell that was left out (wholly
    inside a building) answers with the nearest kept cell above it in the same column, or, when the whole
    column is inside a building taller than the stack, the nearest kept top-layer cell. NaN or infinite
    coordinates raise ValueError.
    """

    def __init__(self, grid: ViewGrid, codec: Any, n_cells: int, view_distance: float, cache_size: int = 1 << 16):
        self.grid = grid
        self.codec = codec
        self.n_cells = int(n_cells)
        self.view_distance = float(view_distance)
        self._cache: dict[int, np.ndarray] = {}
        self._cache_size = int(cache_size)
        self._resolve = _resolve_grid(grid.index)
        # flat Python lists: scalar indexing of a list is several times faster than of a numpy array
        self._own_flat = grid.index.ravel().tolist()
        self._resolve_flat = self._resolve.ravel().tolist()
        self._x0, self._y0, self._size = float(grid.x0), float(grid.y0), float(grid.size)
        self._nx, self._ny, self._nz = grid.nx, grid.ny, grid.nz

    @classmethod
    def from_topology(cls, topo: Any) -> PvsIndex:
        """The index of a loaded artifact (ValueError when it was built without a PVS)."""
        from topology.pvs_codec import codec_from_arrays

        meta = topo.meta.get("pvs")
        if meta is None or "pvs_grid" not in topo.extra:
            raise ValueError("the topology has no PVS (built with --no-pvs?)")
        grid = ViewGrid(meta["origin"][0], meta["origin"][1], meta["cell_size"], meta["max_height"],
                        topo.extra["pvs_grid"])  # fmt: skip
        return cls(grid, codec_from_arrays(topo.extra), meta["n_cells"], meta["view_distance"])

    @classmethod
    def from_result(cls, result: PvsResult) -> PvsIndex:
        """The index of a fresh build, through the same codec as the artifact (tests and benchmarks)."""
        from topology.pvs_codec import EncodedPvs

        codec = EncodedPvs.from_arrays(result.to_extra())
        return cls(result.grid, codec, result.n_cells, result.config.view_distance)

    def _grid_cell(self, x: float, y: float, z: float) -> tuple[int, int, int]:
        try:  # math.floor raises for NaN (ValueError) and infinities (OverflowError): no extra checks
            ix = min(max(math.floor((x - self._x0) / self._size), 0), self._nx - 1)
            iy = min(max(math.floor((y - self._y0) / self._size), 0), self._ny - 1)
            iz = min(max(math.floor(z / self._size), 0), self._nz - 1)
        except (ValueError, OverflowError, TypeError):
            raise ValueError(f"position must be finite numbers, got ({x!r}, {y!r}, {z!r})") from None
        return iz, iy, ix

    def view_cell_of(self, x: float, y: float, z: float) -> int:
        """The view cell holding the (clamped) position, or -1 if that grid cell is inside a building."""
        iz, iy, ix = self._grid_cell(x, y, z)
        return self._own_flat[(iz * self._ny + iy) * self._nx + ix]

    def lookup_cell(self, x: float, y: float, z: float) -> int:
        """The view cell whose PVS answers for the position (see the class docstring); -1 only without any."""
        iz, iy, ix = self._grid_cell(x, y, z)
        return self._resolve_flat[(iz * self._ny + iy) * self._nx + ix]

    def pvs(self, view_cell: int) -> np.ndarray:
        """Sorted int32 ids of the visibility cells visible from the view cell (read-only, cached)."""
        hit = self._cache.get(view_cell)
        if hit is not None:
            return hit
        if view_cell < 0:
            return np.zeros(0, np.int32)
        ids = self.codec.decode(view_cell, self.n_cells).astype(np.int32)
        ids.flags.writeable = False
        if len(self._cache) >= self._cache_size:
            self._cache.clear()
        self._cache[view_cell] = ids
        return ids

    def cells_at(self, x: float, y: float, z: float) -> np.ndarray:
        """The PVS for a camera at (x, y, z), local metres."""
        return self.pvs(self.lookup_cell(x, y, z))


def _resolve_grid(index: np.ndarray) -> np.ndarray:
    """Every grid cell -> the view cell answering for it: itself, else the first kept cell above, else the
    nearest kept top-layer cell (columns wholly inside a building taller than the stack)."""
    nz, ny, nx = index.shape
    out = index.copy()
    for iz in range(nz - 2, -1, -1):  # fill from above: the first kept cell above
        hole = out[iz] < 0
        out[iz][hole] = out[iz + 1][hole]
    top = out[nz - 1]
    if (top < 0).any() and (top >= 0).any():
        ky, kx = np.nonzero(top >= 0)
        hy, hx = np.nonzero(top < 0)
        for y, x in zip(hy, hx, strict=True):
            k = int(np.argmin((ky - y) ** 2 + (kx - x) ** 2))
            out[:, y, x] = np.where(out[:, y, x] < 0, top[ky[k], kx[k]], out[:, y, x])
    return out
