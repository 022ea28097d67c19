"""Where many entities are, at once: `Agent.xy()` for a list of agents over arrays, bit for bit.

Why: the honest clients take a GPS fix of about half the entities every tick (1 Hz fixes at 2 Hz ticks), and
`xy()` walks the route and the edge geometry through half a dozen Python calls per point, three points per
entity (its place and 1 m either side for the lane's heading): about 8 us an entity at 3,000 entities. Here
where along its route each entity is comes from the world's `RouteTable` for all at once (or, without one,
`Route.edge_offset`, one bisection per point) and the geometry is looked up for all at once
(`truth_arrays.EdgeArrays.points`, which repeats `NetView.point`'s IEEE operations in the same order); the
heading's norm goes through `math.hypot` itself (numpy's hypot can differ in the last bit), so the positions
are exactly `xy()`'s (tests/sims/engine/test_positions.py). Entities inside an area walk, and bodies that are
not our `Agent`s (another source's), are asked for `xy()`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sims.engine.route_table import RouteTable
from sims.engine.truth_arrays import EdgeArrays, lateral_points, route_points


def positions(bodies: Sequence, edges: EdgeArrays, table: RouteTable | None = None) -> np.ndarray:
    """(n, 2) local positions of `bodies` (the front, in its lane), exactly what each one's `xy()` returns.
    `table`: the world's `RouteTable` (where along its route each entity is, found for all at once); without
    it, one `Route.edge_offset` per point (`truth_arrays.route_points`)."""
    out = np.zeros((len(bodies), 2))
    rows, lat, e, o = route_points(bodies, table)
    on_route = set(rows)
    for i, a in enumerate(bodies):
        if i not in on_route:
            out[i] = a.xy()
    if not rows:
        return out
    idx = np.array(rows)
    out[idx, 0], out[idx, 1] = lateral_points(edges, e, o, lat)
    return out
