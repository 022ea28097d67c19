"""Transit routes as a-priori paths: member ways -> ordered, connected lists of (edge, direction).

Route geometry in OSM is a list of ways, often clipped at the map edge, not always oriented and not always in
order. The member ways are chained into polylines by their shared ends (in member order first, then any chains
whose ends meet), and each polyline is map-matched by a shortest path through its corridor (`match_corridor`),
which is connected by construction and neither turns back at a junction nor follows a cross street that a
sample at a crossing happens to be nearest to. Consecutive polylines are joined by a short shortest path on the
route's network; where none is short enough (the route leaves the extract and comes back) the route is stored
as connected pieces. Every stored route is a connected path: `Path(net, route["edges"])` never raises.
"""

from __future__ import annotations

import math
from collections import Counter

import networkx as nx
import numpy as np
import shapely

from topology.raw import TRAM, VEHICLE

#: ends of member ways closer than this are the same point (OSM ways share nodes; clipped data may not)
JOIN_TOL = 5.0


def chain_ways(way_xy: list[np.ndarray]) -> list[np.ndarray]:
    """Concatenate member ways into polylines: consecutive ways first (flipping each to meet the previous
    one), then chains whose ends meet in any order (relations whose members are not sorted)."""
    chains: list[np.ndarray] = []
    cur: np.ndarray | None = None
    for xy in way_xy:
        if len(xy) < 2:
            continue
        if cur is None:
            cur = xy
            continue
        joined = _join(cur, xy)
        if joined is None:
            chains.append(cur)
            cur = xy
        else:
            cur = joined
    if cur is not None:
        chains.append(cur)
    return _merge_unordered(chains)


def _join(a: np.ndarray, b: np.ndarray, allow_flip_first: bool = True) -> np.ndarray | None:
    """a then b as one polyline if an end of a meets an end of b (within JOIN_TOL), preferring a's end."""
    ends = [(-1, 0), (-1, -1), (0, 0), (0, -1)] if allow_flip_first else [(-1, 0), (-1, -1)]
    d = [math.dist(a[ae], b[be]) for ae, be in ends]
    k = int(np.argmin(d))
    if d[k] > JOIN_TOL:
        return None
    ae, be = ends[k]
    a2 = a if ae == -1 else a[::-1]
    b2 = b if be == 0 else b[::-1]
    return np.vstack([a2, b2[1:] if math.dist(a2[-1], b2[0]) < 1e-6 else b2])


def _merge_unordered(chains: list[np.ndarray]) -> list[np.ndarray]:
    """Join chains whose ends meet, keeping the earlier chain's direction (only an end of a chain that meets
    exactly one other chain's end is joined, so a route's branches are never glued together arbitrarily)."""
    chains = list(chains)
    changed = True
    while changed and len(chains) > 1:
        changed = False
        for i in range(len(chains)):
            for end in (-1, 0):
                p = chains[i][end]
                hits = [(j, e) for j in range(len(chains)) if j != i for e in (0, -1)
                        if math.dist(p, chains[j][e]) <= JOIN_TOL]
                if len({j for j, _ in hits}) != 1:
                    continue
                j = hits[0][0]
                a, b = (chains[i], chains[j]) if end == -1 else (chains[j], chains[i])
                if end == 0:  # i's start meets j: j comes first, oriented to end at i's start
                    joined = _join(b[::-1], a[::-1])  # reversed i then reversed j ...
                    joined = joined[::-1] if joined is not None else None  # ... turned back: j, then i
                else:
                    joined = _join(a, b, allow_flip_first=False)
                if joined is None:
                    continue
                lo, hi = sorted((i, j))
                chains[lo] = joined
                del chains[hi]
                changed = True
                break
            if changed:
                break
    return chains


def sample_polyline(xy: np.ndarray, step: float) -> np.ndarray:
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


def match_polyline(topo, index, graph: nx.MultiGraph, xy: np.ndarray, networks: int,
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
    out = []
    for u, v in zip(nodes, nodes[1:], strict=False):
        k = min(graph[u][v], key=lambda k: graph[u][v][k]["length"])
        out.append([int(k), 1 if int(topo.edge_nodes[k][0]) == u else -1])
    return out


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


def _place_stops(lines: np.ndarray, edges: list[list[int]], raw_stops, max_dist: float = 30.0) -> list[dict]:
    """Stops onto the route's own edges (not the parallel track of the other direction)."""
    route_edges = sorted({e for e, _ in edges})
    sub = lines[route_edges]
    stops = []
    for st in raw_stops:
        pt = shapely.Point(st.xy)
        d = shapely.distance(sub, pt)
        k = int(np.argmin(d))
        if d[k] <= max_dist:
            edge = route_edges[k]
            offset = float(shapely.line_locate_point(sub[k], pt))
            stops.append({"name": st.name, "edge": edge, "offset": round(offset, 2)})
    return stops


def _gaps(chains: list[np.ndarray]) -> float:
    return sum(math.dist(a[-1], b[0]) for a, b in zip(chains, chains[1:], strict=False))


def order_chains(chains: list[np.ndarray], raw_stops) -> list[np.ndarray]:
    """Chains in travel order. A single chain runs the way its stops are listed (an unsorted relation loses
    its direction when chained; the ordered stops keep it). Several chains are put in nearest-neighbour order
    from the chain of the first stop, each turned to start near the previous one's end, when that order has
    less than half the gaps of the members' order (an unsorted relation with a missing way)."""
    if not chains:
        return chains
    if len(chains) == 1:
        if len(raw_stops) >= 2:
            line = shapely.LineString(chains[0])
            first = line.line_locate_point(shapely.Point(raw_stops[0].xy))
            last = line.line_locate_point(shapely.Point(raw_stops[-1].xy))
            if last < first:
                return [chains[0][::-1]]
        return chains
    lines = [shapely.LineString(c) for c in chains]
    k0 = 0
    if raw_stops:
        p0 = shapely.Point(raw_stops[0].xy)
        k0 = int(np.argmin([ln.distance(p0) for ln in lines]))
    rest = [c for k, c in enumerate(chains) if k != k0]
    first = chains[k0]
    # the first chain points at the nearest end of the others
    others = np.vstack([np.vstack([c[0], c[-1]]) for c in rest])
    if np.hypot(*(others - first[0]).T).min() < np.hypot(*(others - first[-1]).T).min():
        first = first[::-1]
    out = [first]
    while rest:
        end = out[-1][-1]
        d = [(min(math.dist(end, c[0]), math.dist(end, c[-1])), k) for k, c in enumerate(rest)]
        _, k = min(d)
        c = rest.pop(k)
        out.append(c if math.dist(end, c[0]) <= math.dist(end, c[-1]) else c[::-1])
    return out if _gaps(out) < 0.5 * _gaps(chains) else chains


def network_graph(topo, networks: int) -> nx.MultiGraph:
    g = nx.MultiGraph()
    for e in np.flatnonzero(topo.edge_networks & networks):
        u, v = topo.edge_nodes[e]
        g.add_edge(int(u), int(v), key=int(e), length=float(topo.edge_length[e]))
    return g


def build_routes(topo, raw_routes, raw_way_xy: dict[int, np.ndarray], report: Counter) -> list[dict]:
    """Match every route relation; a route that cannot be joined into one connected path is stored as its
    connected pieces (`part` 0, 1, ...: the same `id`), counted as repaired:route_split_into_pieces."""
    graphs = {TRAM: network_graph(topo, TRAM), VEHICLE: network_graph(topo, VEHICLE)}
    lines = edge_lines(topo)
    index = topo.placement_index()
    out = []
    for rr in raw_routes:
        bits = TRAM if rr.mode == "tram" else VEHICLE
        chains = order_chains(chain_ways([raw_way_xy[w] for w in rr.way_ids if w in raw_way_xy]), rr.stops)
        parts: list[list[list[int]]] = []
        for xy in chains:
            best = match_corridor(topo, xy, bits)
            if best:
                parts.append([list(de) for de in best])
            else:  # the corridor is broken: snap samples, then join or split what they give
                report["repaired:route_matched_by_samples"] += 1
                parts.extend([de] for de in match_polyline(topo, index, graphs[bits], xy, bits))
        pieces = connected_pieces(topo, graphs[bits], parts, report)
        if not pieces:
            report["dropped:route_not_matched"] += 1
            continue
        if len(pieces) > 1:
            report["repaired:route_split_into_pieces"] += 1
        for k, edges in enumerate(pieces):
            route = {"id": rr.route_id, "mode": rr.mode, "ref": rr.ref, "name": rr.name, "edges": edges,
                     "stops": _place_stops(lines, edges, rr.stops)}
            if len(pieces) > 1:
                route["part"] = k
            out.append(route)
    report["read:routes_matched"] += len({r["id"] for r in out})
    return out
