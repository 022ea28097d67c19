"""The viewers' 500 m radius baseline counts what the PVS counts (issue 11): a cell is within the radius when
any part of its footprint is, as the PVS's own range is measured, not only when its centre is."""

import numpy as np
import shapely

from sims.engine.viewers import radius_cells_at
from tests.entitynet.client_fixtures import cross


def _centre_x(topo, c: int) -> float:
    b = topo.cell_footprints.bounds()[c]
    return (b[0] + b[2]) / 2.0


def test_a_long_cell_reaching_into_the_radius_is_in_it():
    topo = cross(arm=600.0)  # each arm is one 580 m street cell
    west = int(np.argmin([_centre_x(topo, c) for c in range(topo.n_cells)]))
    x = 250.0  # the west arm's near end is about 270 m away, its centre about 560 m
    assert abs(_centre_x(topo, west) - x) > 500.0
    assert west in radius_cells_at(topo, 500.0)(x, 0.0, 1.7)


def test_the_radius_set_is_exactly_the_footprints_within_the_radius():
    topo = cross(arm=600.0, street_cell_max=40.0)
    polys = topo.cell_footprints.to_shapely()
    cells_at = radius_cells_at(topo, 300.0)
    for x, y in [(0.0, 0.0), (250.0, 0.0), (-400.0, 120.0), (590.0, -590.0), (5000.0, 0.0)]:
        want = np.flatnonzero(shapely.dwithin(polys, shapely.Point(x, y), 300.0))
        assert np.array_equal(cells_at(x, y, 1.7), want), (x, y)
