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

from sims.engine.agents import Agent
from sims.engine.route_table import RouteTable
from sims.engine.truth_arrays import EdgeArrays, lateral_points


def positions(bodies: Sequence, edges: EdgeArrays, table: RouteTable | None = None) -> np.ndarray:
    """(n, 2) local positions of `bodies` (the front, in its lane), exactly what each one's `xy()` returns.
    `table`: the world's `RouteTable` (where along its route each entity is, found for all at once); without
    it, one `Route.edge_offset` per point."""
    n = len(bodies)
    out = np.zeros((n, 2))
    rows: list[int] = []
    lat: list[float] = []
    pe: list[int] = []  # three points per entity on its route: its place, 1 m behind, 1 m ahead
    po: list[float] = []
    rts: list[tuple[int, int]] = []
    ss: list[float] = []
    for i, a in enumerate(bodies):
        if type(a) is not Agent or (a.area is not None and a.in_area_since is not None):
            out[i] = a.xy()
            continue
        rows.append(i)
        lat.append(a.lateral)
        if table is not None:
            rts.append(a._rt)
            ss.append(a.s)
            continue
        r = a.route
        s = max(a.s, 0.0)
        e0, o0 = r.edge_offset(s)
        e1, o1 = r.edge_offset(max(s - 1.0, 0.0))
        e2, o2 = r.edge_offset(min(s + 1.0, r.length))
        pe += (e0, e1, e2)
        po += (o0, o1, o2)
    if not rows:
        return out
    if table is not None:
        rt = np.array(rts, dtype=np.int64).reshape(-1, 2)
        s = np.array(ss)
        s = np.where(0.0 > s, 0.0, s)  # max(s, 0.0)
        behind = s - 1.0
        ahead = s + 1.0
        length = table.rlen[rt[:, 0]]
        q = np.stack([s, np.where(0.0 > behind, 0.0, behind), np.where(length < ahead, length, ahead)], axis=1)
        e, o = table.edge_offsets(np.repeat(rt[:, 0], 3), np.repeat(rt[:, 1], 3), q.reshape(-1))
    else:
        e, o = np.array(pe, dtype=np.int64), np.array(po)
    idx = np.array(rows)
    out[idx, 0], out[idx, 1] = lateral_points(edges, e, o, lat)
    return out
