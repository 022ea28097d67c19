"""Ragged polygon arrays: many polygons (with holes) in three flat numpy arrays.

This is how the artifact stores cell footprints, areas and buildings: compact, loadable without shapely,
and convertible to shapely in one vectorised call when a build step or an export needs geometry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Polygons:
    """`ring_offsets[i]:ring_offsets[i+1]` are polygon i's rings (the first is the exterior);
    `coord_offsets[r]:coord_offsets[r+1]` are ring r's closed coordinates in `xy`."""

    ring_offsets: np.ndarray
    coord_offsets: np.ndarray
    xy: np.ndarray

    def __len__(self) -> int:
        return len(self.ring_offsets) - 1

    @classmethod
    def empty(cls) -> Polygons:
        """No polygons (a map without buildings or areas is valid)."""
        return cls(np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros((0, 2), np.float64))

    @classmethod
    def from_shapely(cls, polygons) -> Polygons:
        """Pack shapely polygons into the ragged arrays (build time)."""
        import shapely  # lazily: reading an artifact's polygons needs no shapely, building them does

        geoms = np.asarray(list(polygons), dtype=object)
        if len(geoms) == 0:
            return cls.empty()
        kind, xy, (coord_offsets, ring_offsets) = shapely.to_ragged_array(geoms)
        if kind != shapely.GeometryType.POLYGON:
            raise ValueError(f"expected polygons, got {kind!r}")
        return cls(ring_offsets.astype(np.int64), coord_offsets.astype(np.int64), xy.astype(np.float64))

    def to_shapely(self) -> np.ndarray:
        """The polygons as a shapely array (build steps and exports; the run-time readers never call it)."""
        import shapely

        if len(self) == 0:
            return np.empty(0, dtype=object)
        return shapely.from_ragged_array(
            shapely.GeometryType.POLYGON, self.xy, (self.coord_offsets, self.ring_offsets)
        )

    def exterior(self, i: int) -> np.ndarray:
        """Polygon i's exterior ring as an (n, 2) closed coordinate array."""
        r = self.ring_offsets[i]
        return self.xy[self.coord_offsets[r] : self.coord_offsets[r + 1]]

    def bounds(self) -> np.ndarray:
        """(n, 4) xmin, ymin, xmax, ymax of each polygon, vectorised (holes lie inside the exterior)."""
        out = np.zeros((len(self), 4))
        if len(self) == 0:
            return out
        starts = self.coord_offsets[self.ring_offsets[:-1]]
        out[:, 0] = np.minimum.reduceat(self.xy[:, 0], starts)
        out[:, 1] = np.minimum.reduceat(self.xy[:, 1], starts)
        out[:, 2] = np.maximum.reduceat(self.xy[:, 0], starts)
        out[:, 3] = np.maximum.reduceat(self.xy[:, 1], starts)
        return out
