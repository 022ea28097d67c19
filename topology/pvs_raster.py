"""Rasters for the PVS builder: occluder heights and target labels on a padded pixel grid.

Why its own module: the sweep (`topology.pvs`) works on flat pixel arrays; turning polygons into those
pixels (shapely, once per build) and eroding the occluders is a separate, separately testable step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely


@dataclass
class _Raster:
    """A padded raster: pixel (r, c) has its centre at (gx0 + (c + 0.5) * px, gy0 + (r + 0.5) * px)."""

    gx0: float
    gy0: float
    px: float
    shape: tuple[int, int]

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """x of every column's and y of every row's pixel centre."""
        rows, cols = self.shape
        xs = self.gx0 + (np.arange(cols) + 0.5) * self.px
        ys = self.gy0 + (np.arange(rows) + 0.5) * self.px
        return xs, ys

    def window(self, bounds: tuple[float, float, float, float]) -> tuple[slice, slice]:
        """Row and column slices of the pixels that meet `bounds` (clipped to the raster)."""
        xmin, ymin, xmax, ymax = bounds
        c0 = max(0, int(math.floor((xmin - self.gx0) / self.px)))
        c1 = min(self.shape[1], int(math.ceil((xmax - self.gx0) / self.px)) + 1)
        r0 = max(0, int(math.floor((ymin - self.gy0) / self.px)))
        r1 = min(self.shape[0], int(math.ceil((ymax - self.gy0) / self.px)) + 1)
        return slice(r0, r1), slice(c0, c1)

    def pixel_of(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat pixel index of each point (clamped to the raster)."""
        c = np.clip(np.floor((np.asarray(x) - self.gx0) / self.px).astype(np.int64), 0, self.shape[1] - 1)
        r = np.clip(np.floor((np.asarray(y) - self.gy0) / self.px).astype(np.int64), 0, self.shape[0] - 1)
        return r * self.shape[1] + c


def _rasterise(polys: np.ndarray, raster: _Raster, bounds) -> tuple[np.ndarray, np.ndarray]:
    """(flat pixel, polygon) pairs for pixel centres strictly inside each polygon, within `bounds`."""
    xs, ys = raster.centres()
    pix, owner = [], []
    shapely.prepare(polys)
    bb = shapely.bounds(polys)
    for j, poly in enumerate(polys):
        if poly is None or poly.is_empty:
            continue
        x0, y0, x1, y1 = bb[j]
        rs, cs = raster.window((max(x0, bounds[0]), max(y0, bounds[1]), min(x1, bounds[2]), min(y1, bounds[3])))
        if rs.stop <= rs.start or cs.stop <= cs.start:
            continue
        gx, gy = np.meshgrid(xs[cs], ys[rs])
        inside = shapely.contains_xy(poly, gx, gy)
        rr, cc = np.nonzero(inside)
        pix.append((rr + rs.start) * raster.shape[1] + (cc + cs.start))
        owner.append(np.full(len(rr), j))
    if not pix:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(pix).astype(np.int64), np.concatenate(owner).astype(np.int64)


def _erode(h: np.ndarray, radius_px: float) -> np.ndarray:
    """Grey-scale erosion (minimum over a disk) with the outside counted as open ground (0)."""
    r = int(math.floor(radius_px + 1e-9))
    if r <= 0:
        return h.copy()
    pad = np.pad(h, r, constant_values=0.0)
    out = h.copy()
    rows, cols = h.shape
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dx * dx + dy * dy <= radius_px * radius_px + 1e-9 and (dx or dy):
                np.minimum(out, pad[r + dy : r + dy + rows, r + dx : r + dx + cols], out=out)
    return out
