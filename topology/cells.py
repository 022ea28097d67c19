"""Visibility cells over the cleaned network: junction cells, street cells, area cells, per-edge breakpoints.

- Each street is split near a crossing (a node of degree >= 3), at `junction_radius` from it; the short pieces
  around one crossing form one junction cell (T- or X-shaped).
- Crossings closer together than two junction pieces (plus a minimum street piece) are merged into one junction
  cell when the merged cell stays compact; otherwise the short edge between them is split at the point that
  divides it in proportion to the two radii, so no street cell is shorter than `min_street_piece_m`.
- The remaining centreline pieces become street cells: sweep volumes of constant width, at most
  `max_street_cell_m` long (long streets are split into equal pieces).
- Each area is one extruded area cell.
Every offset of every edge lies in exactly one cell: the breakpoints of an edge start at 0 and increase.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from topology.artifact import CELL_AREA, CELL_JUNCTION, CELL_STREET
from topology.clean import Network


@dataclass
class CellParams:
    """Sizes of the visibility cells: the width is the widest street and the height the tallest entity,
    so one cell shape fits every street (the reference design's sweep volume)."""
    street_width_m: float = 16.0
    entity_height_m: float = 4.5
    junction_radius_m: float | None = None  # default: the street width
    max_street_cell_m: float = 60.0
    min_street_piece_m: float = 4.0
    max_junction_cluster_m: float = 40.0

    @property
    def radius(self) -> float:
        """Distance from a crossing at which its streets are split; the street width unless set."""
        return self.junction_radius_m if self.junction_radius_m is not None else self.street_width_m


@dataclass
class CellSet:
    """The cells as built, before they are packed into the artifact: per cell its kind, footprint, edges and
    nodes, and per edge its breakpoints."""
    kind: list[int] = field(default_factory=list)
    footprints: list[Polygon] = field(default_factory=list)
    edges: list[list[int]] = field(default_factory=list)
    nodes: list[list[int]] = field(default_factory=list)
    #: per edge: sorted list of (start offset, cell id)
    breakpoints: list[list[tuple[float, int]]] = field(default_factory=list)


def cumulative(xy: np.ndarray) -> np.ndarray:
    """Distance along the polyline at each vertex (0 at the first): the table offset lookups search."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])


def substring(xy: np.ndarray, cum: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The polyline between offsets s0 <= s1 (clamped), with interpolated end points."""
    s0 = min(max(s0, 0.0), cum[-1])
    s1 = min(max(s1, s0), cum[-1])

    def point(s: float) -> np.ndarray:
        k = min(max(int(np.searchsorted(cum, s, side="right")) - 1, 0), len(cum) - 2)
        seg = cum[k + 1] - cum[k]
        t = 0.0 if seg <= 0 else (s - cum[k]) / seg
        return xy[k] + t * (xy[k + 1] - xy[k])

    inner = xy[(cum > s0) & (cum < s1)]
    return np.vstack([point(s0), inner, point(s1)])


class _UnionFind:
    def __init__(self) -> None:
        self.parent: dict[int, int] = {}

    def find(self, a: int) -> int:
        self.parent.setdefault(a, a)
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def union(self, a: int, b: int) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[max(ra, rb)] = min(ra, rb)


def build_cells(net: Network, params: CellParams | None = None) -> CellSet:
    """Cut the cleaned network into visibility cells (rules in the module docstring), so that every offset
    of every edge lies in exactly one cell."""
    p = params or CellParams()
    r = p.radius
    area_nodes = {a.node for a in net.areas}
    deg: dict[int, int] = defaultdict(int)
    for e in net.edges:
        deg[e.u] += 1
        deg[e.v] += 1
    is_junction = {n for n, d in deg.items() if d >= 3 and n not in area_nodes}
    lengths = [e.length for e in net.edges]

    # --- merge crossings that are too close for two junction pieces and a street piece between them
    uf = _UnionFind()
    for n in is_junction:
        uf.find(n)
    members: dict[int, set[int]] = {n: {n} for n in is_junction}
    whole_edge_junction: set[int] = set()
    for i in sorted(range(len(net.edges)), key=lambda i: lengths[i]):
        e = net.edges[i]
        if e.u in is_junction and e.v in is_junction and lengths[i] < 2 * r + p.min_street_piece_m:
            ra, rb = uf.find(e.u), uf.find(e.v)
            if ra == rb:
                whole_edge_junction.add(i)
                continue
            merged = members[ra] | members[rb]
            pts = np.asarray([net.node_xy[n] for n in merged])
            extent = float(np.hypot(*(pts.max(axis=0) - pts.min(axis=0))))
            if extent <= p.max_junction_cluster_m:
                uf.union(ra, rb)
                members[uf.find(ra)] = merged
                whole_edge_junction.add(i)

    cells = CellSet()
    junction_cell: dict[int, int] = {}

    def new_cell(kind: int) -> int:
        cells.kind.append(kind)
        cells.footprints.append(Polygon())
        cells.edges.append([])
        cells.nodes.append([])
        return len(cells.kind) - 1

    for n in sorted(is_junction):
        root = uf.find(n)
        if root not in junction_cell:
            junction_cell[root] = new_cell(CELL_JUNCTION)
        cells.nodes[junction_cell[root]].append(n)

    def jcell(n: int) -> int | None:
        return junction_cell[uf.find(n)] if n in is_junction else None

    half = p.street_width_m / 2.0
    junction_pieces: dict[int, list[np.ndarray]] = defaultdict(list)
    street_pieces: list[tuple[int, np.ndarray]] = []
    cells.breakpoints = [[] for _ in net.edges]

    for i, e in enumerate(net.edges):
        L = lengths[i]
        cum = cumulative(e.xy)
        ju, jv = jcell(e.u), jcell(e.v)
        bps = cells.breakpoints[i]
        if i in whole_edge_junction:
            bps.append((0.0, ju))
            junction_pieces[ju].append(e.xy)
            cells.edges[ju].append(i)
            continue
        a = r if ju is not None else 0.0
        b = r if jv is not None else 0.0
        if L < a + b + p.min_street_piece_m:
            # too short for a street piece: the junction(s) take the whole edge
            if ju is not None and jv is not None:
                cut = L * a / (a + b)
                pieces = [(0.0, cut, ju), (cut, L, jv)] if ju != jv else [(0.0, L, ju)]
            else:
                pieces = (
                    [(0.0, L, ju if ju is not None else jv)] if (ju is not None or jv is not None) else []
                )
            if not pieces:  # neither end is a crossing: one (short) street cell
                pieces = [(0.0, L, None)]
        else:
            pieces = []
            if a > 0:
                pieces.append((0.0, a, ju))
            mid = L - a - b
            n_street = max(1, math.ceil(mid / p.max_street_cell_m - 1e-9))
            for k in range(n_street):
                pieces.append((a + mid * k / n_street, a + mid * (k + 1) / n_street, None))
            if b > 0:
                pieces.append((L - b, L, jv))
        for s0, s1, cell in pieces:
            geom = substring(e.xy, cum, s0, s1)
            if cell is None:
                cell = new_cell(CELL_STREET)
                street_pieces.append((cell, geom))
                cells.nodes[cell].extend(n for n, at in ((e.u, s0 <= 0.0), (e.v, s1 >= L)) if at)
            else:
                junction_pieces[cell].append(geom)
            if i not in cells.edges[cell]:
                cells.edges[cell].append(i)
            if bps and bps[-1][1] == cell:
                continue  # contiguous pieces of one cell (a junction on a self-loop) share a breakpoint
            bps.append((float(s0), cell))

    # --- footprints, vectorised where possible
    if street_pieces:
        polys = shapely.buffer(
            np.array([LineString(g) for _, g in street_pieces], dtype=object), half, cap_style="flat"
        )
        for (cell, _), poly in zip(street_pieces, polys, strict=True):
            cells.footprints[cell] = poly
    for cell_id in set(junction_cell.values()):
        geoms = [LineString(g) for g in junction_pieces.get(cell_id, []) if len(g) >= 2]
        arms = shapely.buffer(np.array(geoms, dtype=object), half, cap_style="flat") if geoms else []
        discs = [shapely.Point(net.node_xy[n]).buffer(half, quad_segs=4) for n in cells.nodes[cell_id]]
        cells.footprints[cell_id] = shapely.union_all([*arms, *discs])
    area_cell: dict[int, int] = {}
    for area in net.areas:
        cell = new_cell(CELL_AREA)
        cells.footprints[cell] = area.polygon
        cells.nodes[cell].append(area.node)
        area_cell[area.node] = cell
    for i, e in enumerate(net.edges):  # an area cell points at the streets that reach its area
        for n in (e.u, e.v):
            if n in area_cell and i not in cells.edges[area_cell[n]]:
                cells.edges[area_cell[n]].append(i)
    # polygons only (a union of arms can come out as a MultiPolygon only for a degenerate cluster)
    cells.footprints = [_as_polygon(g) for g in cells.footprints]
    return cells


def _as_polygon(g) -> Polygon:
    if g.geom_type == "Polygon":
        return g
    parts = [x for x in getattr(g, "geoms", []) if x.geom_type == "Polygon"]
    if not parts:
        return Polygon()
    # keep the whole footprint: the convex hull of a fragmented junction covers every arm
    return max(parts, key=lambda x: x.area) if len(parts) == 1 else shapely.convex_hull(g)
