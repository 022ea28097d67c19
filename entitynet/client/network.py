"""A run-time view of the topology for the per-fix path: plain Python lists and cached lookups.

Why lists and not numpy: the hot path touches one edge at a time, and indexing a numpy array yields numpy
scalars whose arithmetic costs ~10x a Python float. The arrays are converted once per process; the geometry
itself stays in the artifact's float64 local coordinates.

Directed edges are pairs (edge, dir) with dir = +1 (offset 0 -> length) or -1 (length -> 0).
"""

from __future__ import annotations

import math
from bisect import bisect_right

from topology.artifact import CELL_JUNCTION, Topology

DirEdge = tuple[int, int]


class NetView:
    """Python-list mirrors of the artifact arrays and the junction rule shared by players and receivers."""

    def __init__(self, topo: Topology) -> None:
        self.topo = topo
        self.n_edges = topo.n_edges
        self.edge_len: list[float] = topo.edge_length.astype(float).tolist()
        self.edge_from: list[int] = topo.edge_nodes[:, 0].astype(int).tolist()
        self.edge_to: list[int] = topo.edge_nodes[:, 1].astype(int).tolist()
        self.edge_net: list[int] = topo.edge_networks.astype(int).tolist()
        self.node_area: list[int] = topo.node_area.astype(int).tolist()
        self.node_x: list[float] = topo.node_xy[:, 0].tolist()
        self.node_y: list[float] = topo.node_xy[:, 1].tolist()
        off = topo.node_edge_offsets
        ne = topo.node_edges.astype(int)
        self.node_edges: list[list[int]] = [ne[off[i] : off[i + 1]].tolist() for i in range(topo.n_nodes)]
        self.geom_off: list[int] = topo.edge_geom_offsets.astype(int).tolist()
        self.gx: list[float] = topo.edge_geom_xy[:, 0].tolist()
        self.gy: list[float] = topo.edge_geom_xy[:, 1].tolist()
        self.gcum: list[float] = topo.edge_geom_cum.astype(float).tolist()
        self.bp_off: list[int] = topo.edge_bp_offsets.astype(int).tolist()
        self.bp_start: list[float] = topo.edge_bp_start.astype(float).tolist()
        self.bp_cell: list[int] = topo.edge_bp_cell.astype(int).tolist()
        self.cell_kind: list[int] = topo.cell_kind.astype(int).tolist()
        self.area_node: list[int] = topo.area_node.astype(int).tolist()
        self.area_cell: list[int] = topo.area_cell.astype(int).tolist()
        self._next_cache: dict[tuple[int, int, int], DirEdge | None] = {}
        self._choice_cache: dict[tuple[int, int, int], list[DirEdge]] = {}
        self._pieces: dict[DirEdge, list[tuple[float, float, int]]] = {}
        self._is_choice: dict[tuple[DirEdge, int], bool] = {}

    # ---- points and cells ---------------------------------------------------------------------------------
    def point(self, edge: int, offset: float) -> tuple[float, float]:
        """(x, y) at `offset` metres along `edge`, clamped to the edge; pure Python, one bisection."""
        lo, hi = self.geom_off[edge], self.geom_off[edge + 1]
        cum = self.gcum
        if offset <= 0.0:
            return self.gx[lo], self.gy[lo]
        if offset >= cum[hi - 1]:
            return self.gx[hi - 1], self.gy[hi - 1]
        if hi - lo == 2:  # one segment: the bisection below can only give lo
            k = lo
        else:
            k = bisect_right(cum, offset, lo, hi) - 1
            k = min(max(k, lo), hi - 2)
        seg = cum[k + 1] - cum[k]
        t = 0.0 if seg <= 0.0 else (offset - cum[k]) / seg
        x0, y0 = self.gx[k], self.gy[k]
        return x0 + t * (self.gx[k + 1] - x0), y0 + t * (self.gy[k + 1] - y0)

    def cell_at(self, edge: int, offset: float) -> int:
        """Visibility cell at an offset along an undirected edge: the plain lookup `Path.cell` writes out."""
        lo, hi = self.bp_off[edge], self.bp_off[edge + 1]
        k = bisect_right(self.bp_start, offset, lo, hi) - 1
        return self.bp_cell[max(k, lo)]

    def pieces(self, edge: int, d: int) -> list[tuple[float, float, int]]:
        """Cell pieces of a directed edge as (start, end, cell) in distances along the direction of travel."""
        hit = self._pieces.get((edge, d))
        if hit is None:
            hit = self._pieces[(edge, d)] = self._make_pieces(edge, d)
        return hit

    def _make_pieces(self, edge: int, d: int) -> list[tuple[float, float, int]]:
        lo, hi = self.bp_off[edge], self.bp_off[edge + 1]
        length = self.edge_len[edge]
        starts = self.bp_start[lo:hi]
        out = []
        for i in range(hi - lo):
            a = max(0.0, min(starts[i], length))
            b = length if i + 1 == hi - lo else max(0.0, min(starts[i + 1], length))
            if b > a or (i + 1 == hi - lo and not out):
                out.append((a, b, self.bp_cell[lo + i]))
        if d > 0:
            return out
        return [(length - b, length - a, c) for a, b, c in reversed(out)]

    # ---- directed edges -----------------------------------------------------------------------------------
    def start_node(self, de: DirEdge) -> int:
        """Node a directed edge leaves from (edge_from when travelling forward, edge_to otherwise)."""
        return self.edge_from[de[0]] if de[1] > 0 else self.edge_to[de[0]]

    def end_node(self, de: DirEdge) -> int:
        """Node a directed edge arrives at: where the junction rule and choice tests look."""
        return self.edge_to[de[0]] if de[1] > 0 else self.edge_from[de[0]]

    def dist_of(self, de: DirEdge, offset: float) -> float:
        """Distance travelled along the directed edge at an edge offset (offsets count from edge_from)."""
        return offset if de[1] > 0 else self.edge_len[de[0]] - offset

    def heading(self, de: DirEdge, at_end: bool) -> tuple[float, float]:
        """Unit direction of travel at the start or end of a directed edge (first/last non-zero segment)."""
        edge, d = de
        lo, hi = self.geom_off[edge], self.geom_off[edge + 1]
        idx = range(hi - 1, lo, -1) if (at_end == (d > 0)) else range(lo, hi - 1)
        for k in idx:
            a, b = (k - 1, k) if (at_end == (d > 0)) else (k, k + 1)
            dx, dy = self.gx[b] - self.gx[a], self.gy[b] - self.gy[a]
            n = math.hypot(dx, dy)
            if n > 1e-9:
                return (dx / n * d, dy / n * d)
        return (0.0, 0.0)

    def choices(self, de: DirEdge, networks: int) -> list[DirEdge]:
        """Directed edges leaving the end node of `de` on `networks` (excluding going straight back)."""
        key = (de[0], de[1], networks)
        hit = self._choice_cache.get(key)
        if hit is not None:
            return hit
        n = self.end_node(de)
        out: list[DirEdge] = []
        for e in sorted(self.node_edges[n]):
            if not (self.edge_net[e] & networks):
                continue
            for d in (1, -1):
                cand = (e, d)
                if self.start_node(cand) != n or cand == (de[0], -de[1]):
                    continue
                if cand not in out:
                    out.append(cand)
        self._choice_cache[key] = out
        return out

    def next_edge(self, de: DirEdge, networks: int) -> DirEdge | None:
        """The documented junction rule when no a-priori route is known: the straightest continuation.

        Largest cosine between the heading arriving at the node and the heading leaving it; ties go to the
        lowest (edge, dir). None at a dead end or an area node (the entity then enters area motion).
        Every player and every receiver applies this same rule, so extrapolations agree.
        """
        key = (de[0], de[1], networks)
        if key in self._next_cache:
            return self._next_cache[key]
        best: DirEdge | None = None
        if self.node_area[self.end_node(de)] < 0:
            hx, hy = self.heading(de, at_end=True)
            best_cos = -2.0
            for cand in self.choices(de, networks):
                cx, cy = self.heading(cand, at_end=False)
                c = round(hx * cx + hy * cy, 9)
                if c > best_cos:
                    best, best_cos = cand, c
        self._next_cache[key] = best
        return best

    def is_choice(self, de: DirEdge, networks: int) -> bool:
        """Whether leaving `de` at its end node is a real choice (more than one way on, or an area)."""
        key = (de, networks)
        hit = self._is_choice.get(key)
        if hit is None:
            hit = self._is_choice[key] = len(self.choices(de, networks)) > 1 or self.node_area[self.end_node(de)] >= 0
        return hit

    def is_junction_cell(self, cell: int) -> bool:
        """Whether a cell is a junction cell (around a node where ways meet) rather than a street or area cell."""
        return self.cell_kind[cell] == CELL_JUNCTION

    def edges_near_nodes(self, nodes: list[int], networks: int) -> list[int]:
        """Edges of the given networks touching any of the nodes, sorted: the candidate set for
        continuity placement (sorted so ties resolve the same way every run)."""
        out = set()
        for n in nodes:
            for e in self.node_edges[n]:
                if self.edge_net[e] & networks:
                    out.add(e)
        return sorted(out)


def netview(topo: Topology) -> NetView:
    """One NetView per Topology object (cached on the object itself)."""
    nv = topo.__dict__.get("_entitynet_netview")
    if nv is None:
        nv = NetView(topo)
        topo.__dict__["_entitynet_netview"] = nv
    return nv

