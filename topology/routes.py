"""Transit routes as a-priori paths: member ways -> ordered, connected lists of (edge, direction).

Route geometry in OSM is a list of ways, often clipped at the map edge, not always oriented and not always in
order. The member ways are chained into polylines by their shared ends (in member order first, then any chains
whose ends meet), and each polyline is map-matched by a shortest path through its corridor
(`topology.matching.match_corridor`, the matcher GTFS shapes use too),
which is connected by construction and neither turns back at a junction nor follows a cross street that a
sample at a crossing happens to be nearest to. Consecutive polylines are joined by a short shortest path on the
route's network; where none is short enough (the route leaves the extract and comes back) the route is stored
as connected pieces. Every stored route is a connected path: `Path(net, route["edges"])` never raises.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import shapely

from topology.matching import connected_pieces, edge_lines, match_corridor, match_samples, network_graph
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
                parts.extend([de] for de in match_samples(topo, index, graphs[bits], xy, bits))
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
