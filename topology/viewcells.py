"""View cells: a regular 3D grid of the free camera's space, from street level to a maximum height.

Why a plain grid: the camera roams freely (street level, rooftops, fly-over), so cells fitted to streets
would leave most of the space uncovered; m-LOMA uses cubes a little smaller than the average building
height for the same reason. Lookup is then pure arithmetic (no search), which keeps it in microseconds.

A view cell wholly inside the buildings is left out (id -1 in the grid index): no camera can be there.
"Wholly inside" is exact: the union of the footprints of all buildings at least as tall as the cell's top
covers the cell's square (shapely, one vectorised `covers` per layer).
"""

from __future__ import annotations

import math

import numpy as np
import shapely

from topology.polygons import Polygons
from topology.viewgrid import ViewGrid

# ViewGrid lives in the shapely-free viewgrid
__all__ = ["MAX_VIEW_CELLS", "ViewGrid", "build_view_grid", "column_squares"]

#: the most view cells one grid may have: a 20 km x 20 km city in 20 m cubes up to 100 m is 5 million; past
#: this the grid's arrays take gigabytes and its PVS days (0.001 m cells ended in a numpy MemoryError)
MAX_VIEW_CELLS = 10_000_000


def column_squares(x0: float, y0: float, size: float, nx: int, ny: int) -> np.ndarray:
    """shapely boxes of all columns, row-major (iy, ix)."""
    iy, ix = np.divmod(np.arange(nx * ny), nx)
    xa = x0 + ix * size
    ya = y0 + iy * size
    return shapely.box(xa, ya, xa + size, ya + size)


def build_view_grid(
    building_footprints: Polygons,
    building_height: np.ndarray,
    bounds: tuple[float, float, float, float],
    size: float = 20.0,
    max_height: float = 100.0,
) -> ViewGrid:
    """The grid over `bounds` (xmin, ymin, xmax, ymax), without view cells wholly inside buildings."""
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    if not all(math.isfinite(v) for v in (xmin, ymin, xmax, ymax)) or xmax <= xmin or ymax <= ymin:
        raise ValueError(f"bad bounds {bounds!r}")
    if not (size > 0 and math.isfinite(size)) or not (max_height > 0 and math.isfinite(max_height)):
        raise ValueError(f"view-cell size and max height must be positive, got {size}, {max_height}")
    heights = np.asarray(building_height, dtype=np.float64)
    if len(heights) != len(building_footprints):
        raise ValueError("one height per building footprint expected")
    if len(heights) and not np.all(np.isfinite(heights)):
        raise ValueError("building heights must be finite")
    nx = max(1, math.ceil((xmax - xmin) / size - 1e-9))
    ny = max(1, math.ceil((ymax - ymin) / size - 1e-9))
    nz = max(1, math.ceil(max_height / size - 1e-9))
    if nx * ny * nz > MAX_VIEW_CELLS:
        raise ValueError(f"{nx} x {ny} x {nz} view cells of {size:g} m is more than {MAX_VIEW_CELLS:,}: "
                         "choose a larger --view-cell-size (or a lower --view-max-height)")
    inside = np.zeros((nz, ny, nx), dtype=bool)
    polys = building_footprints.to_shapely()
    if len(polys):
        squares = column_squares(xmin, ymin, size, nx, ny)
        polys = shapely.make_valid(polys)
        for iz in range(nz):
            top = min((iz + 1) * size, max_height)
            tall = polys[heights >= top]
            if len(tall) == 0:
                break  # higher layers have even fewer buildings reaching their tops
            union = shapely.union_all(tall)
            shapely.prepare(union)
            inside[iz] = shapely.covers(union, squares).reshape(ny, nx)
    index = np.full((nz, ny, nx), -1, dtype=np.int32)
    free = ~inside
    index[free] = np.arange(int(free.sum()), dtype=np.int32)
    return ViewGrid(xmin, ymin, float(size), float(max_height), index)
