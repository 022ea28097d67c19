"""The view-cell grid as the run-time reader sees it: a regular 3D grid and its id index (numpy only).

Why apart from `topology.viewcells`: building the grid needs shapely (which cells lie inside buildings), reading
it does not, and the run-time PVS lookup (`topology.pvs_index`) must load without shapely.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ViewGrid:
    """Layer k spans z in [k*size, min((k+1)*size, max_height)]; column (iy, ix) spans
    [x0 + ix*size, x0 + (ix+1)*size] x [y0 + iy*size, ...]. `index[iz, iy, ix]` is the view-cell id or -1."""

    x0: float
    y0: float
    size: float
    max_height: float
    index: np.ndarray  # (nz, ny, nx) int32

    @property
    def nz(self) -> int:
        """Layers (height bands) of the grid."""
        return int(self.index.shape[0])

    @property
    def ny(self) -> int:
        """Rows (y) of the grid."""
        return int(self.index.shape[1])

    @property
    def nx(self) -> int:
        """Columns (x) of the grid."""
        return int(self.index.shape[2])

    @property
    def n_view_cells(self) -> int:
        """View cells kept (grid cells not wholly inside a building)."""
        return int((self.index >= 0).sum())

    def layer_top(self, iz: np.ndarray | int) -> np.ndarray:
        """Top z of layer(s) `iz` (the last layer stops at max_height)."""
        return np.minimum((np.asarray(iz) + 1) * self.size, self.max_height)

    def layer_bottom(self, iz: np.ndarray | int) -> np.ndarray:
        """Bottom z of layer(s) `iz`."""
        return np.asarray(iz) * self.size

    def coords(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(iz, iy, ix) of every view cell, ordered by id."""
        iz, iy, ix = np.nonzero(self.index >= 0)
        order = np.argsort(self.index[iz, iy, ix])
        return iz[order], iy[order], ix[order]

    def boxes(self) -> np.ndarray:
        """(V, 6) x0, y0, z0, x1, y1, z1 of every view cell, ordered by id."""
        iz, iy, ix = self.coords()
        x0 = self.x0 + ix * self.size
        y0 = self.y0 + iy * self.size
        return np.column_stack(
            [x0, y0, self.layer_bottom(iz), x0 + self.size, y0 + self.size, self.layer_top(iz)]
        ).astype(np.float64)

    def meta(self) -> dict:
        """The grid's JSON-able description for `meta["pvs"]` (the index itself is an array)."""
        return {
            "origin": [float(self.x0), float(self.y0), 0.0],
            "cell_size": float(self.size),
            "dims": [self.nx, self.ny, self.nz],
            "max_height": float(self.max_height),
        }
