"""Placing fixes on the network: the placement index for the first fix, continuity afterwards.

Continuity projects a fix onto the segments of the edges within two hops of the current edge (one vectorised
numpy pass over a cached segment table, no shapely). Edges the entity is expected on (its path: the route or
the predicted way) get a head start of `switch_margin` metres, and a different edge must win `switch_count`
fixes in a row: that is the hysteresis against flapping between parallel streets under GPS noise. When
nothing nearby is within `reacquire` metres the placement index is asked again.

Ties are deterministic: segments are ordered by (edge id, vertex index) and the first minimum wins, so a fix
exactly on a vertex or equidistant to two edges always gets the same answer.
"""

from __future__ import annotations

import math

import numpy as np

from entitynet.client.network import NetView
from topology.networks import Placement

# a placement result is the placement index's own record: kind "edge" (index = edge, offset along it) or
# kind "area" (index = area); x, y the inferred point; distance from the fix
Fix = Placement
_new_fix = tuple.__new__  # Fix(...) without the NamedTuple's Python-level __new__ (the same tuple)

AREA_BUCKET = 100.0  # metres: grid of area boxes for `areas_near`
PY_ROWS = 160  # segment tables up to this size are searched by a plain loop, larger ones by numpy
# slack (metres) on the box lower bound that lets the loop skip an edge: far above the rounding of a computed
# distance (coordinates of 1e4 m have ulps of 2e-12 m), so a skipped segment can never be the answer
PRUNE_SLACK = 1e-6
RING_PY = 64  # rings up to this many vertices are tested by a plain loop, larger ones by numpy
# segment tables a placer keeps, the least recently used dropped beyond: about 14 KB each (25 segments on the
# bundled map), so at most ~57 MB per placer on any map; the bundled map's 3,499 edges never reach it, a city
# ten times its size would otherwise keep a table for every edge its entities ever reached (bench sim's
# `fleet_memory`, docs/dead-reckoning.md). A dropped table is built again when asked (about 0.2 ms).
TABLES_KEPT = 4096


def ring_distance(ring: np.ndarray, x: float, y: float) -> float:
    """Distance from (x, y) to a closed ring's boundary. A small ring's projections are a plain loop (the same
    IEEE operations as the numpy pass, a dozen numpy calls cost more than the loop) and only the final
    hypot and minimum are numpy's, so the answer is `_ring_distance_np`'s bit for bit (a test)."""
    n = len(ring) - 1
    if n <= 0:
        return math.inf
    if n > RING_PY:
        return _ring_distance_np(ring, x, y)
    pts = ring.tolist()
    exs, eys = [], []
    p0x, p0y = pts[0]
    for p1x, p1y in pts[1:]:
        dx = p1x - p0x
        dy = p1y - p0y
        l2 = dx * dx + dy * dy
        t = ((x - p0x) * dx + (y - p0y) * dy) / (l2 if l2 > 0 else 1.0)
        t = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
        exs.append(p0x + t * dx - x)
        eys.append(p0y + t * dy - y)
        p0x, p0y = p1x, p1y
    return float(np.min(np.hypot(exs, eys)))


def _ring_distance_np(ring: np.ndarray, x: float, y: float) -> float:
    """Distance from (x, y) to a closed ring's boundary (vectorised over its segments)."""
    p0, p1 = ring[:-1], ring[1:]
    d = p1 - p0
    if not len(d):
        return math.inf
    l2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    t = np.clip(((x - p0[:, 0]) * d[:, 0] + (y - p0[:, 1]) * d[:, 1]) / np.where(l2 > 0, l2, 1.0), 0.0, 1.0)
    return float(np.min(np.hypot(p0[:, 0] + t * d[:, 0] - x, p0[:, 1] + t * d[:, 1] - y)))


def segment_rows(geom: tuple[np.ndarray, ...], ed: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The segment rows of edges `ed` in their order (each edge's segments along it), from the network's vertex
    arrays `geom` (`Placer.geom`): per edge its number of segments, and the columns ax, ay, dx, dy, inv_l2 (0.0
    for a segment of no length), slen, cum0 and edge. One home for that arithmetic: the placer's tables and
    the fleet core's (fleet_near.NearTables, many tables in one pass) are built by it."""
    gx, gy, gcum, goff = geom
    lo = goff[ed]
    per = np.maximum(goff[ed + 1] - lo - 1, 0)  # (an edge's last vertex starts no segment)
    rep = np.repeat(np.arange(len(ed)), per)
    k = np.arange(int(per.sum()), dtype=np.int64) - (np.cumsum(per) - per)[rep] + lo[rep]
    ax, ay = gx[k], gy[k]
    dx, dy = gx[k + 1] - ax, gy[k + 1] - ay
    l2 = dx * dx + dy * dy
    return per, {"ax": ax, "ay": ay, "dx": dx, "dy": dy, "inv_l2": np.where(l2 > 0.0, 1.0 / np.where(l2 > 0.0, l2, 1.0),
                 0.0), "slen": np.sqrt(l2), "cum0": gcum[k], "edge": ed[rep]}


class _SegTable:
    __slots__ = ("ax", "ay", "dx", "dy", "inv_l2", "cum0", "slen", "edge", "edges", "areas", "masks", "rows",
                 "slen_py", "cum0_py", "groups", "group_of")

    def __init__(self, geom: tuple[np.ndarray, ...], edges: list[int], areas: list[int]) -> None:
        """The rows of `edges`' segments (sorted by edge, then along it) from the network's vertex arrays `geom`
        (x, y, cumulative length, per-edge offsets: `Placer.geom`), in one numpy pass: the same IEEE operations
        per segment as a loop over the vertices (tests/entitynet/client/test_fleet_near.py compares them)."""
        edges = sorted(set(edges))
        ed = np.array(edges, dtype=np.int64)
        per, cols = segment_rows(geom, ed)
        self.ax, self.ay, self.dx, self.dy = cols["ax"], cols["ay"], cols["dx"], cols["dy"]
        self.inv_l2, self.slen, self.cum0, self.edge = cols["inv_l2"], cols["slen"], cols["cum0"], cols["edge"]
        self.edges = edges
        self.areas = areas
        self.masks: dict[frozenset[int], np.ndarray] = {}
        # the same numbers as Python floats, one tuple per segment: most tables hold 10-30 segments, where a
        # plain loop is several times faster than a dozen numpy calls (and gives the same IEEE results)
        self.rows = list(zip(self.ax.tolist(), self.ay.tolist(), self.dx.tolist(), self.dy.tolist(),
                             self.inv_l2.tolist(), self.edge.tolist(), strict=True))
        self.slen_py: list[float] = self.slen.tolist()
        self.cum0_py: list[float] = self.cum0.tolist()
        # per edge, in table order: (edge, box of its vertices, first row, end row), for skipping whole edges
        # (the box of each segment's two ends, a + d as the loop computed them)
        self.groups: list[tuple[int, float, float, float, float, int, int]] = []
        self.group_of: dict[int, tuple[int, float, float, float, float, int, int]] = {}
        if len(self.edge):
            has = per > 0
            first = (np.cumsum(per) - per)[has]
            bx, by = self.ax + self.dx, self.ay + self.dy
            boxes = zip(ed[has].tolist(), np.minimum.reduceat(np.minimum(self.ax, bx), first).tolist(),
                        np.minimum.reduceat(np.minimum(self.ay, by), first).tolist(),
                        np.maximum.reduceat(np.maximum(self.ax, bx), first).tolist(),
                        np.maximum.reduceat(np.maximum(self.ay, by), first).tolist(), first.tolist(),
                        (first + per[has]).tolist(), strict=True)
            for g in boxes:
                self.groups.append(g)
                self.group_of[g[0]] = g

    def mask(self, preferred: frozenset[int]) -> np.ndarray:
        m = self.masks.get(preferred)
        if m is None:
            if len(self.masks) > 64:
                self.masks.clear()
            m = self.masks[preferred] = np.isin(self.edge, np.fromiter(preferred, np.int64, len(preferred)))
        return m


class Placer:
    """Per-process placement service shared by all entities on one topology and network mask."""

    def __init__(self, net: NetView, networks: int, *, switch_margin: float = 3.0, switch_count: int = 2,
                 reacquire: float = 40.0, tables_kept: int = TABLES_KEPT) -> None:
        if tables_kept < 1:
            raise ValueError(f"a placer keeps at least one segment table, got {tables_kept}")
        self.net = net
        self.topo = net.topo
        self.networks = networks
        self.switch_margin = switch_margin
        self.switch_count = switch_count
        self.reacquire = reacquire
        self.tables_kept = int(tables_kept)
        # edge (or ("route", edges) for `on_edges`) -> its table, least recently used first
        self._tables: dict[int | tuple, _SegTable] = {}
        self._rings: dict[int, np.ndarray] = {}
        self._segs: dict[int, list[tuple[float, ...]]] = {}
        self._ring_box: dict[int, tuple[float, float, float, float, bool]] = {}
        self._ring_segs: dict[int, list[tuple[float, float, float, float]]] = {}
        self._area_bounds: tuple[np.ndarray, np.ndarray] | None = None
        self._area_rows: dict[tuple[int, int], list[tuple[int, float, float, float, float]]] | None = None
        self._grid: tuple[dict[tuple[int, int], list[int]], dict, float] | None = None
        self._geom: tuple[np.ndarray, ...] | None = None

    # ---- first fix -----------------------------------------------------------------------------------------
    def first(self, x: float, y: float) -> Fix | None:
        """First placement of an entity, from the topology's placement index (None: the map has none of
        the type's networks); continuity takes over after it."""
        p = self.topo.placement_index().place(x, y, self.networks)
        if p is None:
            return None
        return p

    @property
    def geom(self) -> tuple[np.ndarray, ...]:
        """The network's vertex x, y, cumulative length and per-edge vertex offsets as numpy arrays (converted
        once per NetView from its lists, kept on it as `placer_for` keeps the placers: one copy for all the
        placers of a map), for building segment tables in one pass."""
        if self._geom is None:
            net = self.net
            geom = net.__dict__.get("_vertex_arrays")
            if geom is None:
                geom = net.__dict__["_vertex_arrays"] = (
                    np.array(net.gx, dtype=float), np.array(net.gy, dtype=float), np.array(net.gcum, dtype=float),
                    np.array(net.geom_off, dtype=np.int64))
            self._geom = geom
        return self._geom

    # ---- continuity ----------------------------------------------------------------------------------------
    def table(self, edge: int) -> _SegTable:
        """The cached segment table of the edges within two hops of `edge`, the only candidates continuity
        projects a fix onto (built once per edge, reused for every later fix near it, up to `tables_kept`
        tables)."""
        return self._table(edge, None)

    def _table(self, key: int | tuple, edges: list[int] | None) -> _SegTable:
        """The table under `key` (an edge: its neighbourhood's; else of `edges`), now the most recently used;
        built when absent, the least recently used dropped beyond `tables_kept`."""
        tables = self._tables
        t = tables.pop(key, None)
        if t is None:
            t = _SegTable(self.geom, *self.neighbourhood(key)) if edges is None else _SegTable(self.geom, edges, [])
            while len(tables) >= self.tables_kept:
                del tables[next(iter(tables))]
        tables[key] = t
        return t

    def neighbourhood(self, edge: int) -> tuple[list[int], list[int]]:
        """The edges of `table(edge)` (within two hops of `edge`, sorted) and the areas at their nodes."""
        net = self.net
        hop1 = net.edges_near_nodes([net.edge_from[edge], net.edge_to[edge]], self.networks)
        nodes = {net.edge_from[e] for e in hop1} | {net.edge_to[e] for e in hop1}
        hop2 = net.edges_near_nodes(sorted(nodes), self.networks)
        return sorted(set(hop2) | {edge}), sorted({net.node_area[n] for n in nodes if net.node_area[n] >= 0})

    def on_edges(self, x: float, y: float, edges: list[int]) -> Fix:
        """Nearest point on a given set of edges (a route), in one vectorised pass; cached per edge set."""
        t = self._table(("route", tuple(sorted(set(edges)))), list(edges))
        rx, ry = x - t.ax, y - t.ay
        u = np.clip((rx * t.dx + ry * t.dy) * t.inv_l2, 0.0, 1.0)
        ex, ey = rx - u * t.dx, ry - u * t.dy
        d = np.sqrt(ex * ex + ey * ey)
        k = int(np.argmin(d))
        return Fix("edge", int(t.edge[k]), float(t.cum0[k] + u[k] * t.slen[k]), float(t.ax[k] + u[k] * t.dx[k]),
                   float(t.ay[k] + u[k] * t.dy[k]), float(d[k]))

    def edges_near(self, x: float, y: float, r: float) -> list[int]:
        """Edges of this placer's networks passing within a box of half-size r around (x, y): every edge
        whose bounding box meets the box (closed intervals), in edge order. The same answer as a query of
        the placement index's STRtree (`_edges_near_tree`, a test), from a grid of buckets in plain Python,
        because it runs at every publish without a route."""
        grid = self._grid
        if grid is None:
            grid = self._grid = self._edge_grid()
        cells, boxes, size = grid
        x0, y0, x1, y1 = x - r, y - r, x + r, y + r
        out: set[int] = set()
        for gx in range(math.floor(x0 / size), math.floor(x1 / size) + 1):
            for gy in range(math.floor(y0 / size), math.floor(y1 / size) + 1):
                for e in cells.get((gx, gy), ()):
                    bx0, by0, bx1, by1 = boxes[e]
                    if not (bx0 > x1 or bx1 < x0 or by0 > y1 or by1 < y0):
                        out.add(e)
        return sorted(out)

    def _edge_grid(self, size: float = 50.0) -> tuple[dict[tuple[int, int], list[int]], dict, float]:
        """Buckets of `size` metres listing the edges (of this placer's networks) whose boxes reach them."""
        net = self.net
        cells: dict[tuple[int, int], list[int]] = {}
        boxes: dict[int, tuple[float, float, float, float]] = {}
        for e in range(net.n_edges):
            if not net.edge_net[e] & self.networks:
                continue
            lo, hi = net.geom_off[e], net.geom_off[e + 1]
            xs, ys = net.gx[lo:hi], net.gy[lo:hi]
            b = boxes[e] = (min(xs), min(ys), max(xs), max(ys))
            for gx in range(math.floor(b[0] / size), math.floor(b[2] / size) + 1):
                for gy in range(math.floor(b[1] / size), math.floor(b[3] / size) + 1):
                    cells.setdefault((gx, gy), []).append(e)
        return cells, boxes, size

    def _edges_near_tree(self, x: float, y: float, r: float) -> list[int]:
        """`edges_near` by the placement index's STRtree (the reference for the grid)."""
        import shapely

        index = self.topo.placement_index()
        box = shapely.box(x - r, y - r, x + r, y + r)
        out: set[int] = set()
        for bit, (tree, idx) in index.trees.items():
            if bit & self.networks and len(idx):
                out.update(int(e) for e in idx[tree.query(box)])
        return sorted(out)

    def areas_near(self, x: float, y: float, r: float) -> list[int]:
        """Areas of this placer's networks whose boundary box is within r of (x, y) (bounding-box test)."""
        b = self._area_bounds
        if b is None:
            b = self.topo.area_polygons.bounds()
            ok = (self.topo.area_networks & self.networks) != 0 if len(b) else np.zeros(0, bool)
            b = self._area_bounds = (b, ok)
        bounds, ok = b
        if not len(bounds):
            return []
        grid = self._area_rows
        if grid is None:  # buckets of areas by box; the same comparisons as the numpy test on the candidates
            grid = self._area_rows = {}
            for i in np.flatnonzero(ok).tolist():
                row = (i, *bounds[i].tolist())
                for gx in range(math.floor(row[1] / AREA_BUCKET), math.floor(row[3] / AREA_BUCKET) + 1):
                    for gy in range(math.floor(row[2] / AREA_BUCKET), math.floor(row[4] / AREA_BUCKET) + 1):
                        grid.setdefault((gx, gy), []).append(row)
        out: set[int] = set()
        # the 1 m pad: bx0 - r <= x may hold by rounding while x + r < bx0 (the buckets must not miss it)
        for gx in range(math.floor((x - r - 1.0) / AREA_BUCKET), math.floor((x + r + 1.0) / AREA_BUCKET) + 1):
            for gy in range(math.floor((y - r - 1.0) / AREA_BUCKET), math.floor((y + r + 1.0) / AREA_BUCKET) + 1):
                for i, bx0, by0, bx1, by1 in grid.get((gx, gy), ()):
                    if bx0 - r <= x and x <= bx1 + r and by0 - r <= y and y <= by1 + r:
                        out.add(i)
        return sorted(out)

    def ring(self, area: int) -> np.ndarray:
        """Exterior ring of an area polygon as a contiguous array, cached: point-in-area runs per fix."""
        r = self._rings.get(area)
        if r is None:
            r = np.ascontiguousarray(self.topo.area_polygons.exterior(area))
            self._rings[area] = r
        return r

    def inside_area(self, area: int, x: float, y: float) -> bool:
        """Even-odd point in polygon on the exterior ring (numpy, no shapely)."""
        r = self.ring(area)
        b = self._ring_box.get(area)
        if b is None:
            b = self._ring_box[area] = (float(r[:, 0].min()) - 1.0, float(r[:, 1].min()),
                                        float(r[:, 0].max()) + 1.0, float(r[:, 1].max()),
                                        bool(len(r) > 1 and (r[0] == r[-1]).all()))
        # outside the ring's box the crossing count below is 0 (above, below, right) or, for a closed ring,
        # even (left): the same answer without the numpy pass. The 1 m pads absorb the rounding of xs.
        if y < b[1] or y >= b[3] or x > b[2] or (b[4] and x < b[0]):
            return False
        segs = self._ring_segs.get(area)
        if segs is None:
            segs = self._ring_segs[area] = (list(zip(r[:-1, 0].tolist(), r[:-1, 1].tolist(), r[1:, 0].tolist(),
                                                     r[1:, 1].tolist(), strict=True))
                                            if len(r) <= RING_PY else [])
        if segs:  # the numpy pass below as a plain loop (a small ring: most areas have about 12 vertices)
            inside = False
            for x0, y0, x1, y1 in segs:
                # crossing edges only: there y1 != y0, and the xs below is the numpy pass's value
                if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
                    inside = not inside
            return inside
        x0, y0, x1, y1 = r[:-1, 0], r[:-1, 1], r[1:, 0], r[1:, 1]
        cond = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xs = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        return bool(np.count_nonzero(cond & (x < xs)) % 2)

    def holds_area(self, area: int, x: float, y: float, edge_distance: float, radius: float) -> bool:
        """Whether a fix just outside `area` still means inside it: within `radius` of its boundary, and the
        boundary nearer than the nearest way (`edge_distance`) by the switch margin. An entity leaves an area
        on a way, so leaving needs a way at least as near as the area; noise alone is not an exit."""
        d = ring_distance(self.ring(area), x, y)
        return d <= radius and d + self.switch_margin < edge_distance

    def near(self, x: float, y: float, edge: int, preferred: set[int] | frozenset[int],
             margin: float | None = None) -> tuple[Fix, float]:
        """Best placement near `edge` with the head start (`margin`, default switch_margin) for `preferred`.

        Returns (fix, distance of the best preferred candidate or inf)."""
        t = self.table(edge)
        for a in t.areas:
            if self.topo.area_networks[a] & self.networks and self.inside_area(a, x, y):
                return Fix("area", a, 0.0, x, y, 0.0), math.inf
        if len(t.rows) <= PY_ROWS:
            return self._near_py(t, x, y, preferred, self.switch_margin if margin is None else margin, edge)
        return self._near_np(t, x, y, preferred, margin)

    def _near_py(self, t: _SegTable, x: float, y: float, preferred: set[int] | frozenset[int],
                 margin: float, edge: int | None = None) -> tuple[Fix, float]:
        """`near` as a plain loop: the same operations per segment as the numpy pass, first minimum wins
        (a preferred segment's cost d + 0.0 is d itself, d being a square root >= +0.0).

        Whole edges are skipped when the box of their vertices is farther than the best cost so far (plus
        the margin for an edge that is not preferred), or for a preferred edge farther than the best preferred
        distance: such a segment cannot be the first minimum nor lower the best preferred distance. The
        bounds start from `edge`'s own segments (an answer any later minimum can only improve on)."""
        sqrt = math.sqrt
        rows = t.rows
        if not preferred:
            margin = 0.0  # no preferred edges: every cost is d itself
        # upper bounds of the final best cost and best preferred distance: costs of `edge`'s segments
        ub_cost = ub_pref = math.inf
        g = t.group_of.get(edge) if edge is not None else None
        if g is not None:
            pref = edge in preferred
            for k in range(g[5], g[6]):
                ax, ay, dx, dy, il2, _e = rows[k]
                rx = x - ax
                ry = y - ay
                u = (rx * dx + ry * dy) * il2
                u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
                ex = rx - u * dx
                ey = ry - u * dy
                d = sqrt(ex * ex + ey * ey)
                if pref:
                    if d < ub_pref:
                        ub_pref = d
                    if d < ub_cost:
                        ub_cost = d
                elif d + margin < ub_cost:
                    ub_cost = d + margin
        best_cost = best_pref = math.inf
        best = -1
        bu = bd = 0.0
        slack = PRUNE_SLACK
        for e, bx0, by0, bx1, by1, k0, k1 in t.groups:
            gx = bx0 - x if x < bx0 else (x - bx1 if x > bx1 else 0.0)
            gy = by0 - y if y < by0 else (y - by1 if y > by1 else 0.0)
            lb = (gx if gx > gy else gy) - slack  # below every computed distance to the edge's segments
            if e in preferred:
                is_pref = True
                if lb > best_pref or lb > ub_pref:
                    continue
            else:
                is_pref = False
                if lb + margin > best_cost or lb + margin > ub_cost:
                    continue
            for k in range(k0, k1):
                ax, ay, dx, dy, il2, _e = rows[k]
                rx = x - ax
                ry = y - ay
                u = (rx * dx + ry * dy) * il2
                u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
                ex = rx - u * dx
                ey = ry - u * dy
                d = sqrt(ex * ex + ey * ey)
                if is_pref:
                    cost = d
                    if d < best_pref:
                        best_pref = d
                else:
                    cost = d + margin
                if cost < best_cost:
                    best_cost, best, bu, bd = cost, k, u, d
        if best < 0:  # no segment beat inf: let numpy's argmin decide
            return self._near_np(t, x, y, preferred, margin)
        ax, ay, dx, dy, _il2, e = rows[best]
        return Fix("edge", e, t.cum0_py[best] + bu * t.slen_py[best], ax + bu * dx, ay + bu * dy, bd), best_pref

    def _near_np(self, t: _SegTable, x: float, y: float, preferred: set[int] | frozenset[int],
                 margin: float | None) -> tuple[Fix, float]:
        """`near` as one vectorised numpy pass (tables larger than PY_ROWS segments)."""
        rx = x - t.ax
        ry = y - t.ay
        u = np.clip((rx * t.dx + ry * t.dy) * t.inv_l2, 0.0, 1.0)
        ex = rx - u * t.dx
        ey = ry - u * t.dy
        d = np.sqrt(ex * ex + ey * ey)
        if preferred:
            pref = t.mask(frozenset(preferred))
            cost = d + np.where(pref, 0.0, self.switch_margin if margin is None else margin)
            dp = np.where(pref, d, np.inf)
            kp = int(np.argmin(dp))
            best_pref = float(dp[kp])
        else:
            cost = d
            best_pref = math.inf
        k = int(np.argmin(cost))
        e = int(t.edge[k])
        off = float(t.cum0[k] + u[k] * t.slen[k])
        return Fix("edge", e, off, float(t.ax[k] + u[k] * t.dx[k]), float(t.ay[k] + u[k] * t.dy[k]),
                   float(d[k])), best_pref

    def project_on(self, x: float, y: float, edge: int) -> Fix:
        """Projection onto one given edge (used to follow the current edge inside the hysteresis)."""
        segs = self._segs.get(edge)
        if segs is None:
            segs = self._segs[edge] = self._edge_segs(edge)
        best_d = math.inf
        found = False
        hypot = math.hypot
        bu = bc0 = bsl = bpx = bpy = 0.0
        for ax, ay, dx, dy, l2, c0, sl in segs:
            if l2 <= 0.0:
                u = 0.0
            else:
                u = ((x - ax) * dx + (y - ay) * dy) / l2
                u = 0.0 if u < 0.0 else (1.0 if u > 1.0 else u)
            px, py = ax + u * dx, ay + u * dy
            dd = hypot(x - px, y - py)
            if dd < best_d:
                best_d, found, bu, bc0, bsl, bpx, bpy = dd, True, u, c0, sl, px, py
        if not found:
            return Fix("edge", edge, 0.0, 0.0, 0.0, math.inf)
        return _new_fix(Fix, ("edge", edge, bc0 + bu * bsl, bpx, bpy, best_d))

    def _edge_segs(self, edge: int) -> list[tuple[float, ...]]:
        """(ax, ay, dx, dy, l2, cum0, seg_len) of each segment of an edge: the per-fix projection's table,
        computed once (the same float operations as computing them per fix)."""
        net = self.net
        out = []
        for k in range(net.geom_off[edge], net.geom_off[edge + 1] - 1):
            ax, ay = net.gx[k], net.gy[k]
            dx, dy = net.gx[k + 1] - ax, net.gy[k + 1] - ay
            out.append((ax, ay, dx, dy, dx * dx + dy * dy, net.gcum[k], net.gcum[k + 1] - net.gcum[k]))
        return out
