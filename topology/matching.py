"""Map matching: polylines (OSM route ways, GTFS shapes, GTFS stop sequences) onto connected directed edges.

Why one module: OSM route relations (`topology.routes`) and GTFS shapes (`topology.gtfs`) are the same
problem, a polyline near the network that must become a connected path, and they use the same matcher,
`match_corridor` (a shortest path through the polyline's corridor). Around it: `match_samples`, the fallback
where the corridor is not connected; `connected_pieces`, which joins matched parts by short gap fillers or
splits them; and `route_by_stops` for a line known only by its stops. Every one of them turns a node path into
directed edges the same way (`path_edges`).
"""

from __future__ import annotations

from collections import Counter

import networkx as nx
import numpy as np
import shapely


def network_graph(topo, networks: int) -> nx.MultiGraph:
    """The edges of `networks` as an undirected multigraph keyed by edge id, weighted by length."""
    g = nx.MultiGraph()
    for e in np.flatnonzero(topo.edge_networks & networks):
        u, v = topo.edge_nodes[e]
        g.add_edge(int(u), int(v), key=int(e), length=float(topo.edge_length[e]))
    return g

def sample_polyline(xy: np.ndarray, step: float) -> np.ndarray:
    """Points every `step` metres along the polyline (both ends included; one point if it has no length)."""
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    if cum[-1] <= 0:
        return xy[:1]
    s = np.linspace(0.0, cum[-1], max(2, int(cum[-1] / step) + 1))
    return np.column_stack([np.interp(s, cum, xy[:, 0]), np.interp(s, cum, xy[:, 1])])


def edge_lines(topo) -> np.ndarray:
    """The edges as shapely LineStrings (once per topology: matching many routes reuses them)."""
    cache = topo.__dict__.setdefault("_route_cache", {})
    if "lines" not in cache:
        cache["lines"] = shapely.from_ragged_array(shapely.GeometryType.LINESTRING, topo.edge_geom_xy,
                                                   (topo.edge_geom_offsets,))
    return cache["lines"]

def match_corridor(topo, xy: np.ndarray, networks: int, *, corridor: float = 25.0,
                   scale: float = 6.0) -> list[tuple[int, int]]:
    """Map-match a polyline by a shortest path through its corridor.

    Every edge of `networks` within `corridor` metres of the polyline may be used, in the direction in which
    it advances along the polyline, at a cost of length * (1 + (mean distance / scale)^2): the cheapest path
    from the node nearest the polyline's start to the node nearest its end follows the polyline, and is
    connected by construction (unlike snapping samples to the nearest edge, which flips between the two
    tracks of a double-track tram line and takes the cross street at a crossing)."""
    line = shapely.LineString(xy)
    lines = edge_lines(topo)
    cand = np.flatnonzero((topo.edge_networks & networks) != 0)
    cand = cand[shapely.dwithin(lines[cand], line, corridor)]
    if len(cand) == 0:
        return []
    g = nx.DiGraph()
    for e in cand.tolist():
        geom = lines[e]
        length = float(topo.edge_length[e])
        n_s = max(2, int(length / 5.0) + 1)
        pts = shapely.line_interpolate_point(geom, np.linspace(0.0, length, n_s))
        d = float(shapely.distance(pts, line).mean())
        pos = shapely.line_locate_point(line, pts[[0, -1]])
        u, v = int(topo.edge_nodes[e][0]), int(topo.edge_nodes[e][1])
        cost = length * (1.0 + (d / scale) ** 2)
        fwd = (u, v, 1) if pos[1] >= pos[0] else (v, u, -1)
        for a, b, dirn, c in ((*fwd, cost), (fwd[1], fwd[0], -fwd[2], cost * 20.0 + 50.0)):
            if a == b:
                continue
            if not g.has_edge(a, b) or g[a][b]["cost"] > c:
                g.add_edge(a, b, cost=c, edge=e, dir=dirn)
    if g.number_of_nodes() == 0:
        return []
    nodes = np.array(list(g.nodes))
    nxy = topo.node_xy[nodes]
    start = int(nodes[np.argmin(np.hypot(*(nxy - xy[0]).T))])
    end = int(nodes[np.argmin(np.hypot(*(nxy - xy[-1]).T))])
    try:
        route = nx.shortest_path(g, start, end, weight="cost")
    except nx.NetworkXNoPath:
        return []
    return [(int(g[a][b]["edge"]), int(g[a][b]["dir"])) for a, b in zip(route, route[1:], strict=False)]

def path_edges(topo, graph: nx.MultiGraph, nodes: list[int]) -> list[list[int]]:
    """A node path of `graph` as directed edges [[edge, +1|-1], ...], the shortest edge between two nodes
    (the one conversion used by the gap filler, the sample matcher and the stop router)."""
    out = []
    for u, v in zip(nodes, nodes[1:], strict=False):
        k = min(graph[u][v], key=lambda k: graph[u][v][k]["length"])
        out.append([int(k), 1 if int(topo.edge_nodes[k][0]) == u else -1])
    return out


def route_by_stops(topo, graph: nx.MultiGraph, xy: np.ndarray) -> list[tuple[int, int]]:
    """A line known only by its stops (a GTFS trip without a shape): shortest network paths between the nodes
    nearest its consecutive stops, one connected route ([] when two stops are not connected on the network).
    An edge driven there and straight back (a stop beside the street) is dropped, as in `connected_pieces`."""
    nodes = np.array(sorted(graph.nodes))
    if len(nodes) == 0:
        return []
    nxy = topo.node_xy[nodes]
    near = [int(nodes[np.argmin(np.hypot(*(nxy - p).T))]) for p in xy]
    seq = [n for k, n in enumerate(near) if k == 0 or n != near[k - 1]]
    out: list[list[int]] = []
    for a, b in zip(seq, seq[1:], strict=False):
        try:
            path = nx.shortest_path(graph, a, b, weight="length")
        except nx.NetworkXNoPath:
            return []
        out.extend(path_edges(topo, graph, path))
    return [(e, d) for e, d in _drop_uturns(out)]

def match_samples(topo, index, graph: nx.MultiGraph, xy: np.ndarray, networks: int,
                   max_dist: float = 15.0, step: float = 5.0) -> list[list[int]]:  # fmt: skip
    """Map-match a polyline by snapping samples to the nearest edge: [[edge, +1|-1], ...] in travel order, gaps
    closed by short shortest paths when possible. The fallback where the corridor is not connected (the route
    runs over a way that is not in its network): its output may have gaps, which `connected_pieces` handles."""
    pts = sample_polyline(xy, step)
    edges, dists = index.nearest_edges(pts, networks)
    seq: list[tuple[int, float]] = []  # (edge, offset of the sample) runs
    runs: list[list[float]] = []
    for p, e, d in zip(pts, edges, dists, strict=True):
        if e < 0 or d > max_dist:
            continue
        off = float(np.hypot(*(topo.edge_polyline(e) - p).T).argmin())  # vertex index as a coarse offset
        if seq and seq[-1][0] == e:
            runs[-1].append(off)
            continue
        seq.append((int(e), off))
        runs.append([off])
    path: list[list[int]] = []
    prev_node: int | None = None
    for (e, _), offs in zip(seq, runs, strict=True):
        u, v = (int(n) for n in topo.edge_nodes[e])
        if len(offs) > 1 and offs[-1] != offs[0]:
            direction = 1 if offs[-1] > offs[0] else -1
        elif prev_node is not None:
            direction = 1 if prev_node == u else -1 if prev_node == v else 1
        else:
            direction = 1
        start = u if direction == 1 else v
        if prev_node is not None and start != prev_node:
            try:
                nodes = nx.shortest_path(graph, prev_node, start, weight="length")
                if len(nodes) <= 6:
                    path.extend(path_edges(topo, graph, nodes))
            except nx.NetworkXNoPath:
                pass
        if path and path[-1][0] == e:
            continue
        path.append([e, direction])
        prev_node = v if direction == 1 else u
    return path

def _end(topo, de) -> int:
    return int(topo.edge_nodes[de[0]][1 if de[1] > 0 else 0])


def _start(topo, de) -> int:
    return int(topo.edge_nodes[de[0]][0 if de[1] > 0 else 1])


def _bridge(topo, graph: nx.MultiGraph, a: int, b: int, straight: float) -> list[list[int]] | None:
    """The shortest network path from node a to node b if it is a plausible gap filler: at most
    1.5 x the straight gap + 50 m (a route that leaves the extract and comes back is not joined)."""
    if a == b:
        return []
    if a not in graph or b not in graph:
        return None
    limit = 1.5 * straight + 50.0
    try:
        length, nodes = nx.single_source_dijkstra(graph, a, b, cutoff=limit, weight="length")
    except nx.NetworkXNoPath:
        return None
    return path_edges(topo, graph, nodes)


def _drop_uturns(edges: list[list[int]]) -> list[list[int]]:
    """Remove an edge driven there and straight back (a join that overshot): the path stays connected."""
    out: list[list[int]] = []
    for de in edges:
        if out and out[-1][0] == de[0] and out[-1][1] == -de[1]:
            out.pop()
        else:
            out.append(de)
    return out


def connected_pieces(topo, graph: nx.MultiGraph, parts: list[list[list[int]]],
                     report: Counter) -> list[list[list[int]]]:
    """Join consecutive matched parts by short shortest paths; split where they cannot be joined. Every
    returned piece is a connected path (an edge's end node is the next edge's start node)."""
    pieces: list[list[list[int]]] = []
    cur: list[list[int]] = []
    for part in parts:
        if not part:
            continue
        if cur:
            a, b = _end(topo, cur[-1]), _start(topo, part[0])
            gap = float(np.hypot(*(topo.node_xy[a] - topo.node_xy[b])))
            fill = _bridge(topo, graph, a, b, gap)
            if fill is not None:
                if a != b:
                    report["repaired:route_gap_joined"] += 1
                cur = _drop_uturns(cur + fill + part)
                continue
            pieces.append(cur)
            cur = []
        cur = list(part)
    if cur:
        pieces.append(cur)
    # the invariant, checked: split at anything that still does not meet (never expected)
    out: list[list[list[int]]] = []
    for piece in pieces:
        run: list[list[int]] = []
        for de in piece:
            if run and _end(topo, run[-1]) != _start(topo, de):
                out.append(run)
                run = []
            run.append(de)
        if run:
            out.append(run)
    return [p for p in out if p]
