"""Small synthetic topologies for the client tests: a cross, a T, a hairpin, a chain of short edges, an area.

`make_topology` builds a complete `topology.artifact.Topology` (same arrays as the real builder writes) from
named nodes and edges, with the reference's cell rule: pieces within `junction_radius` of a node of degree >= 3
form that node's junction cell; the rest of each edge is one street cell (or several of at most
`street_cell_max` metres); an area node's area cell takes the last `junction_radius` metres of its edges.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon
from shapely.ops import substring

from topology.artifact import CELL_AREA, CELL_JUNCTION, CELL_STREET, Topology
from topology.polygons import Polygons
from topology.raw import PEDESTRIAN, TRAM, VEHICLE

ALL = PEDESTRIAN | VEHICLE | TRAM


def _csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.zeros(len(lists) + 1, np.int64)
    offsets[1:] = np.cumsum([len(x) for x in lists])
    flat = np.array([v for x in lists for v in x], dtype=np.int32)
    return offsets, flat


def make_topology(
    nodes: dict[str, tuple[float, float]],
    edges: Sequence[tuple],
    *,
    junction_radius: float = 10.0,
    street_cell_max: float | None = None,
    areas: Sequence[tuple[str, Sequence[tuple[float, float]], int]] = (),
    routes: Sequence[dict] = (),
    origin: tuple[float, float] = (0.0, 0.0),
) -> Topology:
    """`edges`: (from_name, to_name[, networks[, [intermediate (x, y), ...]]]).
    `areas`: (area_node_name, polygon ring, networks). `routes`: artifact route dicts with edge indices."""
    names = list(nodes)
    nid = {n: i for i, n in enumerate(names)}
    node_xy = np.array([nodes[n] for n in names], dtype=np.float64)
    n_nodes = len(names)
    area_of_node = {name: i for i, (name, _ring, _net) in enumerate(areas)}
    node_area = np.array([area_of_node.get(n, -1) for n in names], dtype=np.int32)

    e_nodes, e_net, geoms = [], [], []
    for spec in edges:
        a, b = spec[0], spec[1]
        net = spec[2] if len(spec) > 2 else ALL
        mid = list(spec[3]) if len(spec) > 3 else []
        pts = [nodes[a], *mid, nodes[b]]
        e_nodes.append((nid[a], nid[b]))
        e_net.append(net)
        geoms.append(np.array(pts, dtype=np.float64))
    node_edges: list[list[int]] = [[] for _ in range(n_nodes)]
    for e, (a, b) in enumerate(e_nodes):
        node_edges[a].append(e)
        if b != a:
            node_edges[b].append(e)
    degree = [len(x) for x in node_edges]

    geom_offsets = [0]
    geom_xy, geom_cum, lengths = [], [], []
    for g in geoms:
        seg = np.hypot(*np.diff(g, axis=0).T)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        geom_xy.append(g)
        geom_cum.append(cum)
        lengths.append(float(cum[-1]))
        geom_offsets.append(geom_offsets[-1] + len(g))

    # cells: junction cells per node of degree >= 3, area cells per area node, street cells per edge piece
    cell_kind: list[int] = []
    cell_pieces: list[list[tuple[int, float, float]]] = []
    cell_nodes_l: list[list[int]] = []
    node_cell: dict[int, int] = {}
    for n in range(n_nodes):
        if node_area[n] >= 0:
            node_cell[n] = len(cell_kind)
            cell_kind.append(CELL_AREA)
            cell_pieces.append([])
            cell_nodes_l.append([n])
        elif degree[n] >= 3:
            node_cell[n] = len(cell_kind)
            cell_kind.append(CELL_JUNCTION)
            cell_pieces.append([])
            cell_nodes_l.append([n])
    bp_offsets, bp_start, bp_cell = [0], [], []
    for e, (a, b) in enumerate(e_nodes):
        length = lengths[e]
        lo_end = junction_radius if a in node_cell else 0.0
        hi_start = length - junction_radius if b in node_cell else length
        if lo_end > hi_start:  # junction cells back to back: split at the middle
            lo_end = hi_start = 0.5 * length if (a in node_cell and b in node_cell) else min(lo_end, hi_start)
        pieces: list[tuple[float, float, int]] = []
        if a in node_cell and lo_end > 0.0:
            pieces.append((0.0, lo_end, node_cell[a]))
        if hi_start > lo_end:
            span = hi_start - lo_end
            k = 1 if not street_cell_max else max(1, math.ceil(span / street_cell_max))
            for i in range(k):
                c = len(cell_kind)
                cell_kind.append(CELL_STREET)
                cell_pieces.append([])
                cell_nodes_l.append([])
                pieces.append((lo_end + span * i / k, lo_end + span * (i + 1) / k, c))
        if b in node_cell and hi_start < length:
            pieces.append((hi_start, length, node_cell[b]))
        if not pieces:
            c = len(cell_kind)
            cell_kind.append(CELL_STREET)
            cell_pieces.append([])
            cell_nodes_l.append([])
            pieces.append((0.0, length, c))
        for s0, s1, c in pieces:
            bp_start.append(s0)
            bp_cell.append(c)
            cell_pieces[c].append((e, s0, s1))
        bp_offsets.append(len(bp_start))

    n_cells = len(cell_kind)
    footprints = []
    cell_edges_l: list[list[int]] = []
    for c in range(n_cells):
        parts = []
        for e, s0, s1 in cell_pieces[c]:
            line = LineString(geoms[e])
            sub = substring(line, s0, s1) if s1 > s0 else line.interpolate(s0)
            parts.append(sub.buffer(8.0))
        if node_area.tolist() and c in node_cell.values():
            for n, cc in node_cell.items():
                if cc == c and node_area[n] >= 0:
                    parts.append(Polygon(areas[node_area[n]][1]))
        geom = shapely.union_all(parts) if parts else Polygon([(0, 0), (1, 0), (1, 1)])
        if geom.geom_type != "Polygon":
            geom = geom.convex_hull
        footprints.append(geom)
        cell_edges_l.append(sorted({e for e, _a, _b in cell_pieces[c]}))

    ce_off, ce = _csr(cell_edges_l)
    cn_off, cn = _csr(cell_nodes_l)
    ne_off, ne = _csr(node_edges)
    area_node = np.array([nid[name] for name, _r, _n in areas], dtype=np.int32)
    area_cell = np.array([node_cell[nid[name]] for name, _r, _n in areas], dtype=np.int32)
    area_networks = np.array([net for _name, _r, net in areas], dtype=np.uint8)
    area_polys = Polygons.from_shapely([Polygon(r) for _n, r, _net in areas]) if areas else Polygons.empty()
    meta = {
        "crs": "EPSG:3067",
        "origin": list(origin),
        "bounds": [float(node_xy[:, 0].min()), float(node_xy[:, 1].min()),
                   float(node_xy[:, 0].max()), float(node_xy[:, 1].max())],
        "params": {"junction_radius": junction_radius},
        "routes": list(routes),
        "digest": "synthetic",
    }
    return Topology(
        meta=meta,
        node_xy=node_xy,
        node_area=node_area,
        node_edge_offsets=ne_off,
        node_edges=ne,
        edge_nodes=np.array(e_nodes, dtype=np.int32).reshape(-1, 2),
        edge_networks=np.array(e_net, dtype=np.uint8),
        edge_length=np.array(lengths, dtype=np.float64),
        edge_geom_offsets=np.array(geom_offsets, dtype=np.int64),
        edge_geom_xy=np.concatenate(geom_xy) if geom_xy else np.zeros((0, 2)),
        edge_geom_cum=np.concatenate(geom_cum) if geom_cum else np.zeros(0),
        edge_bp_offsets=np.array(bp_offsets, dtype=np.int64),
        edge_bp_start=np.array(bp_start, dtype=np.float64),
        edge_bp_cell=np.array(bp_cell, dtype=np.int32),
        cell_kind=np.array(cell_kind, dtype=np.uint8),
        cell_height=np.full(n_cells, 4.0, dtype=np.float32),
        cell_footprints=Polygons.from_shapely(footprints),
        cell_edge_offsets=ce_off,
        cell_edges=ce,
        cell_node_offsets=cn_off,
        cell_nodes=cn,
        area_node=area_node,
        area_cell=area_cell,
        area_networks=area_networks,
        area_polygons=area_polys,
        building_height=np.zeros(0, dtype=np.float32),
        building_footprints=Polygons.empty(),
    )


# ---- the standard shapes -------------------------------------------------------------------------------------
def cross(arm: float = 100.0, junction_radius: float = 20.0, **kw) -> Topology:
    """An X crossing at C with four arms W, E, S, N; edges 0: W->C, 1: C->E, 2: S->C, 3: C->N."""
    nodes = {"C": (0.0, 0.0), "W": (-arm, 0.0), "E": (arm, 0.0), "S": (0.0, -arm), "N": (0.0, arm)}
    edges = [("W", "C"), ("C", "E"), ("S", "C"), ("C", "N")]
    return make_topology(nodes, edges, junction_radius=junction_radius, **kw)


def tee(arm: float = 100.0, junction_radius: float = 10.0) -> Topology:
    """A T: edges 0: W->C, 1: C->E, 2: C->S."""
    nodes = {"C": (0.0, 0.0), "W": (-arm, 0.0), "E": (arm, 0.0), "S": (0.0, -arm)}
    return make_topology(nodes, [("W", "C"), ("C", "E"), ("C", "S")], junction_radius=junction_radius)


def hairpin(length: float = 100.0, gap: float = 4.0) -> Topology:
    """One edge going east 100 m, turning, and coming back `gap` metres north of itself."""
    nodes = {"A": (0.0, 0.0), "B": (0.0, gap)}
    mid = [(length, 0.0), (length, gap)]
    return make_topology(nodes, [("A", "B", ALL, mid)])


def chain(n: int = 12, piece: float = 3.0, lead: float = 50.0) -> Topology:
    """A straight line of a `lead` m edge, `n` short edges of `piece` m (degree-2 nodes), and a `lead` m edge;
    every short edge is its own street cell."""
    nodes = {"P0": (0.0, 0.0)}
    x = lead
    nodes["P1"] = (x, 0.0)
    for i in range(n):
        x += piece
        nodes[f"P{i + 2}"] = (x, 0.0)
    nodes[f"P{n + 2}"] = (x + lead, 0.0)
    edges = [(f"P{i}", f"P{i + 1}") for i in range(n + 2)]
    return make_topology(nodes, edges)


def parallel(gap: float = 12.0, length: float = 300.0) -> Topology:
    """Two parallel east-west streets `gap` m apart joined at both ends (for flapping tests)."""
    nodes = {"A": (0.0, 0.0), "B": (length, 0.0), "C": (0.0, gap), "D": (length, gap)}
    return make_topology(nodes, [("A", "B"), ("C", "D"), ("A", "C"), ("B", "D")], junction_radius=5.0)


def area_square(side: float = 60.0) -> Topology:
    """A square pedestrian area (node Q at its centre) with two streets joining it from west and east."""
    h = side / 2
    ring = [(-h, -h), (h, -h), (h, h), (-h, h), (-h, -h)]
    nodes = {"Q": (0.0, 0.0), "W": (-h - 100.0, 0.0), "E": (h + 100.0, 0.0)}
    return make_topology(nodes, [("W", "Q", PEDESTRIAN), ("Q", "E", PEDESTRIAN)],
                         areas=[("Q", ring, PEDESTRIAN)], junction_radius=h)
