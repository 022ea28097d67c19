"""Cleaning: raw, non-topological map ways -> a topological network of nodes, edges and area nodes.

Real map data is not topological and has errors (the reference author cleaned his by hand). The steps, each
counted in the build report:
1. per way: drop non-finite vertices, repeated points, zero-length ways;
2. join ways at shared nodes, except where ways of different layers (bridges, tunnels) share an interior node;
   ways that cross without a shared node are never joined;
3. split ways into edges at true endpoints (way ends and shared nodes: the osmnx rule);
4. snap dangling endpoints to a node of the same layer within the snap tolerance;
5. drop zero-length and duplicate edges (merging their networks);
6. make areas disjoint and join them to the network: an edge whose networks the area serves is clipped at the
   area's boundary and ends at the area node (the entity is then in the area, at (area node, x, y));
7. merge chains of degree-2 nodes whose edges share networks and layer;
8. drop short dangles; 9. simplify within a tolerance; 10. keep the components that matter.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass

import networkx as nx
import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

from topology.raw import RawMap


@dataclass
class CleanParams:
    """Tolerances of the cleaning steps, in metres (m2 for areas); what each step changes is counted in the
    build report."""
    snap_tolerance_m: float = 1.0
    duplicate_tolerance_m: float = 0.5
    dangle_min_m: float = 2.0
    simplify_tolerance_m: float = 0.3
    min_component_m: float = 30.0
    min_area_m2: float = 20.0


@dataclass
class Edge:
    """A cleaned edge from node `u` to node `v`: polyline, network bits, and layer (bridges and tunnels
    stay apart from what they cross)."""
    u: int
    v: int
    xy: np.ndarray
    networks: int
    layer: int

    @property
    def length(self) -> float:
        """Polyline length in metres, recomputed because cleaning edits the geometry."""
        return float(np.hypot(*np.diff(self.xy, axis=0).T).sum())


@dataclass
class Area:
    """An area after cleaning; `node` is the network node that stands for it (-1 until it is joined)."""
    polygon: Polygon
    kind: str
    networks: int
    name: str
    node: int = -1


@dataclass
class Network:
    """The cleaned network: node positions, edges, areas (each with its node)."""

    node_xy: list[tuple[float, float]]
    edges: list[Edge]
    areas: list[Area]
    report: Counter


def _dedupe_points(xy: np.ndarray, ids: np.ndarray, report: Counter) -> tuple[np.ndarray, np.ndarray]:
    finite = np.all(np.isfinite(xy), axis=1)
    if not finite.all():
        report["repaired:non_finite_vertex"] += int((~finite).sum())
        xy, ids = xy[finite], ids[finite]
    if len(xy) < 2:
        return xy, ids
    step = np.hypot(*np.diff(xy, axis=0).T)
    keep = np.concatenate([[True], step > 1e-6])
    if not keep.all():
        report["repaired:repeated_point"] += int((~keep).sum())
    return xy[keep], ids[keep]


def clean(raw: RawMap, params: CleanParams | None = None) -> Network:
    """Turn a reader's raw ways and areas into a topological network (the steps of the module docstring);
    ValueError when no way of a modelled network is left."""
    p = params or CleanParams()
    report = raw.report
    ways = []
    for w in raw.ways:
        xy, ids = _dedupe_points(np.asarray(w.xy, np.float64), np.asarray(w.node_ids, np.int64), report)
        if len(xy) < 2:
            report["dropped:zero_length_way"] += 1
            continue
        layer = w.layer + (1 if w.bridge and w.layer == 0 else 0) - (1 if w.tunnel and w.layer == 0 else 0)
        ways.append((w.way_id, xy, ids, w.networks, layer))
    if not ways:
        if raw.ways:  # there were ways, but all their points coincide: say that, not "no way of a network"
            n = len(raw.ways)
            what = "its one way of the modelled networks has" if n == 1 else \
                f"its {n} ways of the modelled networks all have"
            raise ValueError(f"the map has no streets: {what} zero length (all its points sit at one place)")
        raise ValueError("the map has no streets: no way of any modelled network (pedestrian, vehicle, tram)")

    # --- 2. node identity: shared OSM node ids join, except interior nodes shared across layers
    layers_of: dict[int, set[int]] = defaultdict(set)
    is_end: set[int] = set()
    for _, _, ids, _, layer in ways:
        for i in ids:
            layers_of[int(i)].add(layer)
        is_end.add(int(ids[0]))
        is_end.add(int(ids[-1]))
    key_index: dict[tuple[int, int], int] = {}
    node_xy: list[tuple[float, float]] = []
    occurrences: Counter = Counter()

    def node_key(nid: int, layer: int) -> tuple[int, int]:
        if len(layers_of[nid]) > 1 and nid not in is_end:
            report["repaired:layer_crossing_not_joined"] += 1
            return (nid, layer)
        return (nid, 0)

    way_keys = []
    for _, xy, ids, _, layer in ways:
        keys = []
        for i, (x, y) in zip(ids, xy, strict=True):
            k = node_key(int(i), layer)
            if k not in key_index:
                key_index[k] = len(node_xy)
                node_xy.append((float(x), float(y)))
            keys.append(key_index[k])
        way_keys.append(keys)
        for n in set(keys[1:-1]) | {keys[0], keys[-1]}:
            occurrences[n] += 1
        # a way passing the same node twice (self-touching) splits there too
        for n, c in Counter(keys[1:-1]).items():
            if c > 1:
                occurrences[n] += 1

    # --- 3. split at true endpoints
    edges: list[Edge] = []
    for (_, xy, _, bits, layer), keys in zip(ways, way_keys, strict=True):
        start = 0
        for i in range(1, len(keys)):
            if i == len(keys) - 1 or occurrences[keys[i]] > 1:
                edges.append(Edge(keys[start], keys[i], xy[start : i + 1].copy(), bits, layer))
                start = i
    report["read:edges_before_cleaning"] += len(edges)

    edges = _snap_dangles(node_xy, edges, p, report)
    edges = _drop_degenerate(node_xy, edges, p, report)
    areas = _disjoint_areas(raw, p, report)
    edges = _join_areas(node_xy, edges, areas, p.snap_tolerance_m, report)
    edges = _merge_degree2(edges, {a.node for a in areas}, report)
    edges = _drop_dangles(edges, {a.node for a in areas}, p, report)
    _simplify(edges, p, report)
    edges, areas = _keep_components(node_xy, edges, areas, p, report)
    if not edges:
        raise ValueError("the map has no streets left after cleaning")
    return _renumber(node_xy, edges, areas, report)


def _degree(edges: list[Edge]) -> Counter:
    deg: Counter = Counter()
    for e in edges:
        deg[e.u] += 1
        deg[e.v] += 1
    return deg


def _snap_dangles(node_xy, edges: list[Edge], p: CleanParams, report: Counter) -> list[Edge]:
    """Snap a dangling end to the nearest node of the same layer within the tolerance (an undershoot)."""
    deg = _degree(edges)
    layer_of: dict[int, int] = {}
    for e in edges:
        layer_of.setdefault(e.u, e.layer)
        layer_of.setdefault(e.v, e.layer)
    nodes = np.array(sorted(deg), dtype=np.int64)
    pts = shapely.points(np.asarray([node_xy[n] for n in nodes]))
    tree = shapely.STRtree(pts)
    dangling = [n for n in nodes if deg[n] == 1]
    if not dangling:
        return edges
    neighbours: dict[int, set[int]] = defaultdict(set)
    for e in edges:
        neighbours[e.u].add(e.v)
        neighbours[e.v].add(e.u)
    src, dst = tree.query(shapely.points(np.asarray([node_xy[n] for n in dangling])), predicate="dwithin",
                          distance=p.snap_tolerance_m)  # fmt: skip
    target: dict[int, int] = {}
    best: dict[int, float] = {}
    for s, d in zip(src, dst, strict=True):
        a, b = int(dangling[s]), int(nodes[d])
        if a == b or b in neighbours[a] or layer_of[a] != layer_of[b] or b in target:
            continue
        dist = math.dist(node_xy[a], node_xy[b])
        if dist < best.get(a, math.inf):
            best[a], target[a] = dist, b
    # never snap two dangles onto each other both ways
    for a, b in list(target.items()):
        if target.get(b) == a and a > b:
            del target[a]
    for e in edges:
        if e.u in target:
            e.u = target[e.u]
            e.xy[0] = node_xy[e.u]
        if e.v in target:
            e.v = target[e.v]
            e.xy[-1] = node_xy[e.v]
    report["repaired:snapped_endpoint"] += len(target)
    return edges


def _drop_degenerate(node_xy, edges: list[Edge], p: CleanParams, report: Counter) -> list[Edge]:
    out: list[Edge] = []
    seen: dict[tuple[int, int], list[Edge]] = defaultdict(list)
    for e in edges:
        if e.length < 1e-3 or (e.u == e.v and e.length < 2 * p.snap_tolerance_m):
            report["dropped:zero_length_segment"] += 1
            continue
        key = (min(e.u, e.v), max(e.u, e.v))
        dup = None
        for other in seen[key]:
            a = LineString(e.xy)
            if shapely.hausdorff_distance(a, LineString(other.xy)) <= p.duplicate_tolerance_m:
                dup = other
                break
        if dup is not None:
            if dup.networks | e.networks != dup.networks:
                report["repaired:duplicate_merged_networks"] += 1
            dup.networks |= e.networks
            report["dropped:duplicate_segment"] += 1
            continue
        seen[key].append(e)
        out.append(e)
    return out


def _disjoint_areas(raw: RawMap, p: CleanParams, report: Counter) -> list[Area]:
    """Areas overlap in real data (a square that is also a pedestrian area); keep the smallest, cut the rest."""
    areas: list[Area] = []
    taken = None
    for ra in sorted(raw.areas, key=lambda a: a.polygon.area):
        poly = ra.polygon if taken is None else ra.polygon.difference(taken)
        if taken is not None and poly.area < ra.polygon.area - 1e-6:
            report["repaired:area_overlap_removed"] += 1
        parts = [
            g for g in getattr(poly, "geoms", [poly]) if g.geom_type == "Polygon" and g.area >= p.min_area_m2
        ]
        if not parts:
            report["dropped:area_covered_or_tiny"] += 1
            continue
        for part in parts:
            areas.append(
                Area(shapely.make_valid(part) if not part.is_valid else part, ra.kind, ra.networks, ra.name)
            )
        taken = ra.polygon if taken is None else taken.union(ra.polygon)
    return areas


def _join_areas(node_xy, edges: list[Edge], areas: list[Area], tolerance: float, report: Counter) -> list[Edge]:
    """Give each area a node, and clip the edges it serves at its boundary so that they end at that node."""
    if not areas:
        return edges
    for a in areas:
        rp = a.polygon.representative_point()
        a.node = len(node_xy)
        node_xy.append((rp.x, rp.y))
    lines = np.array([LineString(e.xy) for e in edges], dtype=object)
    tree = shapely.STRtree(lines)
    polys = np.array([a.polygon for a in areas], dtype=object)
    a_idx, e_idx = tree.query(polys, predicate="intersects")
    hits: dict[int, list[int]] = defaultdict(list)
    for ai, ei in zip(a_idx, e_idx, strict=True):
        if edges[ei].networks & ~areas[ai].networks == 0:
            hits[int(ei)].append(int(ai))
    out: list[Edge] = []
    for ei, e in enumerate(edges):
        if ei not in hits:
            out.append(e)
            continue
        line = lines[ei]
        pieces: list[tuple[float, float, np.ndarray]] = []
        outside = line
        for ai in hits[ei]:
            outside = outside.difference(areas[ai].polygon)
        parts = [g for g in getattr(outside, "geoms", [outside]) if not g.is_empty and g.length > 1e-3]
        for g in parts:
            c = np.asarray(g.coords)
            s0, s1 = line.project(shapely.Point(c[0])), line.project(shapely.Point(c[-1]))
            if s1 < s0:
                c, s0, s1 = c[::-1], s1, s0
            pieces.append((s0, s1, c))
        if not pieces:
            report["repaired:edge_inside_area"] += 1
        total = line.length
        served = [areas[ai] for ai in hits[ei]]
        for s0, s1, c in sorted(pieces, key=lambda t: t[0]):
            u = e.u if s0 <= 1e-6 else _nearest_area_node(served, c[0])
            v = e.v if s1 >= total - 1e-6 else _nearest_area_node(served, c[-1])
            out.append(Edge(u, v, c, e.networks, e.layer))
        if pieces and (len(pieces) > 1 or pieces[0][0] > 1e-6 or pieces[0][1] < total - 1e-6):
            report["repaired:edge_clipped_at_area"] += 1
    return _join_touching_nodes(node_xy, out, areas, tolerance, report)


def _join_touching_nodes(node_xy, edges: list[Edge], areas: list[Area], tolerance: float, report: Counter):
    """A street node on (or within the snap tolerance of) an area's boundary becomes the area node, when every
    edge at that node is one the area serves (else the node stays, so other networks keep their junction)."""
    inc: dict[int, list[int]] = defaultdict(list)
    for i, e in enumerate(edges):
        inc[e.u].append(i)
        inc[e.v].append(i)
    area_nodes = {a.node for a in areas}
    candidates = [n for n in inc if n not in area_nodes]
    if not candidates:
        return edges
    tree = shapely.STRtree(np.array([a.polygon for a in areas], dtype=object))
    pts = shapely.points(np.asarray([node_xy[n] for n in candidates]))
    src, dst = tree.query(pts, predicate="dwithin", distance=tolerance)
    remap: dict[int, int] = {}
    for s, d in zip(src, dst, strict=True):
        n, area = candidates[s], areas[d]
        if n in remap:
            continue
        if all(edges[i].networks & ~area.networks == 0 for i in inc[n]):
            remap[n] = area.node
    for e in edges:
        e.u = remap.get(e.u, e.u)
        e.v = remap.get(e.v, e.v)
    report["repaired:node_joined_to_area"] += len(remap)
    return [e for e in edges if not (e.u == e.v and e.u in area_nodes)]


def _nearest_area_node(areas: list[Area], pt: np.ndarray) -> int:
    """The node of the area whose boundary a clipped edge ends on."""
    p = shapely.Point(pt)
    return min(areas, key=lambda a: a.polygon.exterior.distance(p)).node


def _merge_degree2(edges: list[Edge], keep_nodes: set[int], report: Counter) -> list[Edge]:
    """Merge chains through nodes of degree 2 whose two edges share networks and layer."""
    inc: dict[int, list[int]] = defaultdict(list)
    for i, e in enumerate(edges):
        inc[e.u].append(i)
        inc[e.v].append(i)
    alive = [True] * len(edges)
    merged = 0
    for n in list(inc):
        if n in keep_nodes:
            continue
        ids = [i for i in inc[n] if alive[i]]
        if len(ids) != 2 or ids[0] == ids[1]:
            continue
        a, b = edges[ids[0]], edges[ids[1]]
        if a.networks != b.networks or a.layer != b.layer or a is b:
            continue
        # orient a to end at n and b to start at n
        if a.v != n:
            a.u, a.v, a.xy = a.v, a.u, a.xy[::-1].copy()
        if b.u != n:
            b.u, b.v, b.xy = b.v, b.u, b.xy[::-1].copy()
        if a.u == n or b.v == n:  # a loop through n only
            continue
        a.xy = np.vstack([a.xy, b.xy[1:]])
        a.v = b.v
        alive[ids[1]] = False
        inc[b.v] = [ids[0] if i == ids[1] else i for i in inc[b.v]]
        inc[n] = []
        merged += 1
    report["repaired:degree2_chain_merged"] += merged
    return [e for e, ok in zip(edges, alive, strict=True) if ok]


def _drop_dangles(edges: list[Edge], keep_nodes: set[int], p: CleanParams, report: Counter) -> list[Edge]:
    for _ in range(2):
        deg = _degree(edges)
        out = []
        for e in edges:
            dangle = (deg[e.u] == 1 and e.u not in keep_nodes) or (deg[e.v] == 1 and e.v not in keep_nodes)
            both = deg[e.u] == 1 and deg[e.v] == 1
            if dangle and not both and e.length < p.dangle_min_m:
                report["dropped:short_dangle"] += 1
                continue
            out.append(e)
        if len(out) == len(edges):
            break
        edges = out
    return edges


def _simplify(edges: list[Edge], p: CleanParams, report: Counter) -> None:
    if not edges:
        return
    lines = shapely.simplify(np.array([LineString(e.xy) for e in edges], dtype=object), p.simplify_tolerance_m,
                             preserve_topology=False)  # fmt: skip
    removed = 0
    for e, g in zip(edges, lines, strict=True):
        c = np.asarray(g.coords)
        if len(c) >= 2 and len(c) < len(e.xy):
            removed += len(e.xy) - len(c)
            c[0], c[-1] = e.xy[0], e.xy[-1]
            e.xy = c
    report["repaired:vertices_simplified"] += removed


def _keep_components(node_xy, edges: list[Edge], areas: list[Area], p: CleanParams, report: Counter):
    g = nx.MultiGraph()
    for i, e in enumerate(edges):
        g.add_edge(e.u, e.v, key=i, length=e.length)
    for a in areas:
        g.add_node(a.node)
    area_nodes = {a.node for a in areas}
    drop_edges: set[int] = set()
    drop_nodes: set[int] = set()
    for comp in nx.connected_components(g):
        sub = g.subgraph(comp)
        total = sum(d["length"] for _, _, d in sub.edges(data=True))
        if total < p.min_component_m and not (comp & area_nodes):
            drop_edges.update(k for _, _, k in sub.edges(keys=True))
            drop_nodes.update(comp)
            report["dropped:small_component"] += 1
    return [e for i, e in enumerate(edges) if i not in drop_edges], areas


def _renumber(node_xy, edges: list[Edge], areas: list[Area], report: Counter) -> Network:
    used = sorted({n for e in edges for n in (e.u, e.v)} | {a.node for a in areas})
    new = {old: i for i, old in enumerate(used)}
    for e in edges:
        e.u, e.v = new[e.u], new[e.v]
    for a in areas:
        a.node = new[a.node]
    return Network([node_xy[o] for o in used], edges, areas, report)
