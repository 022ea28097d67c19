"""The view-cell grid refuses a cell count no machine holds, with one line, before allocating anything."""

from __future__ import annotations

import numpy as np
import pytest

from topology.polygons import Polygons
from topology.viewcells import MAX_VIEW_CELLS, build_view_grid


def _no_buildings() -> tuple[Polygons, np.ndarray]:
    return Polygons.from_shapely([]), np.zeros(0)


@pytest.mark.parametrize(("bounds", "size", "height"), [
    ((0.0, 0.0, 1e5, 1e5), 0.001, 100.0),  # was a numpy _ArrayMemoryError traceback
    ((0.0, 0.0, 200.0, 200.0), 2.0, 1e5),  # ~5e8 cells: gigabytes, then hours
])
def test_a_view_cell_count_above_the_cap_is_refused_before_allocating(bounds, size, height):
    polys, heights = _no_buildings()
    with pytest.raises(ValueError, match=r"view cells.*--view-cell-size"):
        build_view_grid(polys, heights, bounds, size, height)


def test_a_grid_under_the_cap_is_built():
    polys, heights = _no_buildings()
    grid = build_view_grid(polys, heights, (0.0, 0.0, 100.0, 60.0), 20.0, 100.0)
    assert (grid.nx, grid.ny, grid.nz) == (5, 3, 5) and grid.n_view_cells == 75 <= MAX_VIEW_CELLS
