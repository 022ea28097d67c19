"""The truth of every entity at one instant as arrays: positions and occupied cells, for the truth measure.

Why: a sample of truth against viewers asked each entity for `xy()` and `cells()`, which walk the route and the
edge geometry through half a dozen Python calls per point (three points per entity: its place and 1 m either
side for the lane's heading), about a third of a sample's cost at 1,600 entities. Here where along its route
each entity is comes from the world's `RouteTable` for all at once (`route_points`; without one, one
bisection per point on the route's cumulative distances), and the edge geometry and cell breakpoints are
looked up for all entities at once over the artifact's flat arrays (`EdgeArrays`).

Exact: the lookups repeat `NetView.point`, `NetView.cell_at` and `Route.xy`'s IEEE operations in the same
order (the global search is corrected to the same index a per-edge bisection finds; the heading's norm goes
through `math.hypot` itself), so `TruthArrays` holds bit for bit what `xy()` and `cells()` return
(tests/sims/engine/test_truth_arrays.py). Entities that are not on their route (inside an area walk) and
another source's bodies are asked for `xy()` and `cells()` as before, and bodies with a length (cars, buses,
trams) for the cells their length covers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from entitynet.client.network import NetView
from sims.engine.agents import Agent
from sims.engine.route_table import RouteTable


def lateral_points(edges, e: np.ndarray, o: np.ndarray, lat) -> tuple[np.ndarray, np.ndarray]:
    """Each entity's true position: `(e, o)` holds three (edge, offset) places per entity (its place, 1 m
    behind, 1 m ahead), and `lat` its sideways offset; the heading is the chord between the two neighbours,
    normalised with Python's own `hypot` (numpy's differs in the last bit), as `Route.xy` does. The one home of
    that arithmetic for the truth measure and the fleet's fix positions (sims/engine/positions.py)."""
    px, py = edges.points(e, o)
    x0, y0 = px[0::3], py[0::3]
    dx, dy = px[2::3] - px[1::3], py[2::3] - py[1::3]
    norm = np.array([math.hypot(a, b) for a, b in zip(dx.tolist(), dy.tolist(), strict=True)])
    flat = norm <= 1e-9
    with np.errstate(divide="ignore", invalid="ignore"):
        hx = np.where(flat, 1.0, dx / norm)
        hy = np.where(flat, 0.0, dy / norm)
    la = np.array(lat)
    straight = la == 0.0
    return np.where(straight, x0, x0 + la * hy), np.where(straight, y0, y0 - la * hx)

def _floor_index(keys: np.ndarray, vals: np.ndarray, base: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 q: np.ndarray) -> np.ndarray:
    """For each query, the largest j in [lo, hi) with vals[j] <= q (lo when none): what
    `bisect_right(vals, q, lo, hi) - 1` (at least lo) gives. `keys` = vals + the segment's `base`, increasing
    over all segments, finds it to within rounding; the exact comparisons on `vals` then correct it."""
    k = np.searchsorted(keys, base + q, side="right") - 1
    k = np.clip(k, lo, hi - 1)
    last = len(vals) - 1
    for _ in range(len(vals)):  # in practice zero or one step: rounding moves the search by one at most
        up = (k + 1 < hi) & (vals[np.minimum(k + 1, last)] <= q)
        down = (k > lo) & (vals[k] > q)
        if not (up.any() or down.any()):
            break
        k = k + up - down
    return k


def _lift(vals: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-segment bases and search keys (vals + base) increasing over all segments: each segment (values
    non-decreasing within it, `off[i]:off[i + 1]`) starts a metre past the end of the one before."""
    lo, hi = off[:-1], off[1:]
    step = vals[hi[:-1] - 1] - vals[lo[1:]] + 1.0  # from the last value of one segment to the next's first
    base = np.concatenate([[0.0], np.cumsum(step)])
    return base, vals + np.repeat(base, hi - lo)


class EdgeArrays:
    """Points and cells at offsets along undirected edges, for many at once (see the module docstring)."""

    def __init__(self, net: NetView) -> None:
        topo = net.topo
        self.goff = topo.edge_geom_offsets.astype(np.int64)
        self.gcum = topo.edge_geom_cum.astype(np.float64)
        self.gx = topo.edge_geom_xy[:, 0].astype(np.float64)
        self.gy = topo.edge_geom_xy[:, 1].astype(np.float64)
        self.bpoff = topo.edge_bp_offsets.astype(np.int64)
        self.bpstart = topo.edge_bp_start.astype(np.float64)
        self.bpcell = topo.edge_bp_cell.astype(np.int64)
        self.gbase, self.gkeys = _lift(self.gcum, self.goff)
        self.bbase, self.bkeys = _lift(self.bpstart, self.bpoff)

    def points(self, e: np.ndarray, off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) at offset `off` along edge `e`, clamped to the edge: `NetView.point` for each pair."""
        lo, hi = self.goff[e], self.goff[e + 1]
        cum = self.gcum
        k = _floor_index(self.gkeys, cum, self.gbase[e], lo, hi, off)
        k = np.clip(k, lo, hi - 2)
        seg = cum[k + 1] - cum[k]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(seg <= 0.0, 0.0, (off - cum[k]) / seg)
        x0, y0 = self.gx[k], self.gy[k]
        x = x0 + t * (self.gx[k + 1] - x0)
        y = y0 + t * (self.gy[k + 1] - y0)
        first, last = off <= 0.0, off >= cum[hi - 1]
        x = np.where(first, self.gx[lo], np.where(last, self.gx[hi - 1], x))
        y = np.where(first, self.gy[lo], np.where(last, self.gy[hi - 1], y))
        return x, y

    def cells(self, e: np.ndarray, off: np.ndarray) -> np.ndarray:
        """The visibility cell at offset `off` along edge `e`: `NetView.cell_at` for each pair."""
        lo, hi = self.bpoff[e], self.bpoff[e + 1]
        return self.bpcell[_floor_index(self.bkeys, self.bpstart, self.bbase[e], lo, hi, off)]


@dataclass
class TruthArrays:
    """Every live entity at one instant: `ids` ascending, positions `x`, `y`, and the cells each occupies
    (`cell_off[i]:cell_off[i + 1]` into `cells`, front first, as `cells()` lists them)."""

    ids: np.ndarray
    x: np.ndarray
    y: np.ndarray
    cell_off: np.ndarray
    cells: np.ndarray

    def rows(self, ids: np.ndarray) -> np.ndarray:
        """The row of each id, -1 for an id that is not live."""
        r = np.searchsorted(self.ids, ids)
        r = np.minimum(r, max(len(self.ids) - 1, 0))
        ok = (self.ids[r] == ids) if len(self.ids) else np.zeros(len(ids), bool)
        return np.where(ok, r, -1)

    def cells_of(self, row: int) -> tuple[int, ...]:
        """The cells of the entity in `row` (front first)."""
        return tuple(self.cells[self.cell_off[row]:self.cell_off[row + 1]].tolist())


def route_points(bodies: Sequence, table: RouteTable | None = None) -> tuple[list[int], list[float], np.ndarray,
                                                                          np.ndarray]:
    """Where the bodies that are on their route are: their indices in `bodies`, their lateral offsets and the
    (edge, offset) of three points each (the place, 1 m behind, 1 m ahead: `Route.xy`'s, clamped to the route),
    found by the world's `RouteTable` for all at once, or without it one `Route.edge_offset` per point. The
    others (not our `Agent`, or inside an area walk) are left out: ask them. The one home of that lookup for
    the fleet's fix positions (sims/engine/positions.py) and the truth measure."""
    rows: list[int] = []
    lat: list[float] = []
    pe: list[int] = []
    po: list[float] = []
    rts: list[tuple[int, int]] = []
    ss: list[float] = []
    for i, a in enumerate(bodies):
        if type(a) is not Agent or (a.area is not None and a.in_area_since is not None):
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
    if table is None or not rows:
        return rows, lat, np.array(pe, dtype=np.int64), np.array(po)
    rt = np.array(rts, dtype=np.int64).reshape(-1, 2)
    s = np.array(ss)
    s = np.where(0.0 > s, 0.0, s)  # max(s, 0.0)
    behind = s - 1.0
    ahead = s + 1.0
    length = table.rlen[rt[:, 0]]
    q = np.stack([s, np.where(0.0 > behind, 0.0, behind), np.where(length < ahead, length, ahead)], axis=1)
    e, o = table.edge_offsets(np.repeat(rt[:, 0], 3), np.repeat(rt[:, 1], 3), q.reshape(-1))
    return rows, lat, e, o


def truth_arrays(agents: Mapping[int, object], edges: EdgeArrays | None,
                 table: RouteTable | None = None) -> TruthArrays:
    """The truth of `agents` (a world's live entities by id) as arrays. `edges`: the map's `EdgeArrays` (None:
    every entity is asked for `xy()` and `cells()`, as for a source whose bodies are not our agents); `table`:
    the world's `RouteTable` (`route_points`)."""
    ids = sorted(agents)
    n = len(ids)
    x = np.zeros(n)
    y = np.zeros(n)
    bodies = [agents[aid] for aid in ids]
    fast_rows, lat, e, o = route_points(bodies, table) if edges is not None else ([], [], None, None)
    own: dict[int, tuple[int, ...]] = {}  # row -> cells of an entity asked for them
    on_route = set(fast_rows)
    for i, a in enumerate(bodies):
        if i not in on_route:
            x[i], y[i] = a.xy()
            own[i] = tuple(a.cells())
        elif a.params.length > 0.0:  # a body along the route: its cells are the pieces it covers
            own[i] = a.cells()
    cell_count = np.ones(n, dtype=np.int64)
    front = np.zeros(n, dtype=np.int64)
    if fast_rows:
        rows = np.array(fast_rows)
        x[rows], y[rows] = lateral_points(edges, e, o, lat)
        # the front's cell: `Route.cell(min(s, length))` (the place above, s already within the route)
        front[rows] = edges.cells(e[0::3], o[0::3])
    for i, cs in own.items():
        cell_count[i] = len(cs)
    cell_off = np.concatenate([[0], np.cumsum(cell_count)]).astype(np.int64)
    cells = np.repeat(front, cell_count)  # placeholders where an entity listed its own cells
    for i, cs in own.items():
        cells[cell_off[i]:cell_off[i + 1]] = cs
    return TruthArrays(np.array(ids, dtype=np.int64), x, y, cell_off, cells)
