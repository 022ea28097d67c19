"""Transit routes as a-priori paths: ordered member ways -> an ordered, connected list of (edge, direction).

Route geometry in OSM is a list of ways, often clipped at the map edge and not always oriented; the robust way
onto our cleaned network is to chain the member ways into polylines, sample them, snap the samples to the
nearest edge of the route's network, and close gaps with shortest paths on that network.
"""

from __future__ import annotations

import math
from collections import Counter

import networkx as nx
import numpy as np
import shapely

from topology.raw import TRAM, VEHICLE


def chain_ways(way_xy: list[np.ndarray]) -> list[np.ndarray]:
    """Concatenate consecutive member ways into polylines, flipping each to meet the previous one."""
    chains: list[np.ndarray] = []
    cur: np.ndarray | None = None
    for xy in way_xy:
        if cur is None:
            cur = xy
            continue
        ends = [(0, 0), (0, -1), (-1, 0), (-1, -1)]  # (cur end, way end)
        d = [math.dist(cur[ce], xy[we]) for ce, we in ends]
        k = int(np.argmin(d))
        if d[k] > 5.0:
            chains.append(cur)
            cur = xy
            continue
        ce, we = ends[k]
        if ce == 0:
            cur = cur[::-1]
        cur = np.vstack([cur, xy if we == 0 else xy[::-1]])
    if cur is not None:
        chains.append(cur)
    return chains


def sample_polyline(xy: np.ndarray, step: float) -> np.ndarray:
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    if cum[-1] <= 0:
        return xy[:1]
    s = np.linspace(0.0, cum[-1], max(2, int(cum[-1] / step) + 1))
    return np.column_stack([np.interp(s, cum, xy[:, 0]), np.interp(s, cum, xy[:, 1])])


def match_polyline(topo, index, graph: nx.MultiGraph, xy: np.ndarray, networks: int,
                   max_dist: float = 15.0, step: float = 5.0) -> list[list[int]]:  # fmt: skip
    """Map-match a polyline onto the network: [[edge, +1|-1], ...] in travel order (gaps closed when possible)."""
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
                    for a, b in zip(nodes, nodes[1:], strict=False):
                        k = min(graph[a][b], key=lambda k: graph[a][b][k]["length"])
                        path.append([int(k), 1 if int(topo.edge_nodes[k][0]) == a else -1])
            except nx.NetworkXNoPath:
                pass
        if path and path[-1][0] == e:
            continue
        path.append([e, direction])
        prev_node = v if direction == 1 else u
    return path


def _place_stops(index, edges: list[list[int]], raw_stops, max_dist: float = 30.0) -> list[dict]:
    """Stops onto the route's own edges (not the parallel track of the other direction)."""
    route_edges = sorted({e for e, _ in edges})
    lines = index.lines[route_edges]
    stops = []
    for st in raw_stops:
        pt = shapely.Point(st.xy)
        d = shapely.distance(lines, pt)
        k = int(np.argmin(d))
        if d[k] <= max_dist:
            edge = route_edges[k]
            offset = float(shapely.line_locate_point(lines[k], pt))
            stops.append({"name": st.name, "edge": edge, "offset": round(offset, 2)})
    return stops


def network_graph(topo, networks: int) -> nx.MultiGraph:
    g = nx.MultiGraph()
    for e in np.flatnonzero(topo.edge_networks & networks):
        u, v = topo.edge_nodes[e]
        g.add_edge(int(u), int(v), key=int(e), length=float(topo.edge_length[e]))
    return g


def build_routes(topo, raw_routes, raw_way_xy: dict[int, np.ndarray], report: Counter) -> list[dict]:
    index = topo.placement_index()
    graphs = {TRAM: network_graph(topo, TRAM), VEHICLE: network_graph(topo, VEHICLE)}
    out = []
    for rr in raw_routes:
        bits = TRAM if rr.mode == "tram" else VEHICLE
        chains = chain_ways([raw_way_xy[w] for w in rr.way_ids if w in raw_way_xy])
        edges: list[list[int]] = []
        for xy in chains:
            edges.extend(match_polyline(topo, index, graphs[bits], xy, bits))
        if not edges:
            report["dropped:route_not_matched"] += 1
            continue
        stops = _place_stops(index, edges, rr.stops)
        out.append(
            {
                "id": rr.route_id,
                "mode": rr.mode,
                "ref": rr.ref,
                "name": rr.name,
                "edges": edges,
                "stops": stops,
            }
        )
    report["read:routes_matched"] += len(out)
    return out
