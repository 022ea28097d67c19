"""A small OSM street grid with one bus route relation, written in the test (for route matching and for
driving a bus along the stored route). `variant` spoils the relation the ways real extracts do."""

from __future__ import annotations

import random

import networkx as nx
import numpy as np

from tests.topology.test_osm_reader import LAT0, LON0, D, osm_xml

N = 6  # N x N grid nodes, about 100 m apart (2 * D east, D north)


def nid(i: int, j: int) -> int:
    return 1000 + i * 10 + j


def route_map_xml(variant: str = "ok", *, island: bool = False) -> str:
    """The route runs east along row 1 (i 0->3), north up column 3 (j 1->4), east along row 4 (i 3->5).

    variants: "unordered" (members shuffled), "reversed" (every other way drawn backwards), "gap" (one way
    missing from the relation), "mixed" (all three). `island`: a street far east, unconnected, also a member
    (the route leaves the extract and comes back: it cannot be joined)."""
    nodes = [(nid(i, j), (2 * i, j), {}) for i in range(N) for j in range(N)]
    ways, seg, wid = [], {}, 1
    for j in range(N):
        for i in range(N - 1):
            ways.append((wid, [nid(i, j), nid(i + 1, j)], {"highway": "residential"}))
            seg[(i, j, "e")] = wid
            wid += 1
    for i in range(N):
        for j in range(N - 1):
            ways.append((wid, [nid(i, j), nid(i, j + 1)], {"highway": "residential"}))
            seg[(i, j, "n")] = wid
            wid += 1
    members = ([seg[(i, 1, "e")] for i in range(3)] + [seg[(3, j, "n")] for j in range(1, 4)]
               + [seg[(i, 4, "e")] for i in range(3, 5)])
    if variant in ("reversed", "mixed"):
        rev = set(members[1::2])
        ways = [(w, refs[::-1] if w in rev else refs, t) for w, refs, t in ways]
    if variant in ("gap", "mixed"):
        del members[4]
    if variant in ("unordered", "mixed"):
        random.Random(1).shuffle(members)
    # stops (ordered, as in the relation): the first and the last street of the route
    nodes += [(9001, (1, 1), {"highway": "bus_stop", "name": "First"}),
              (9002, (9, 4), {"highway": "bus_stop", "name": "Last"})]
    rel_members = [("w", w, "") for w in members]
    if island:
        nodes += [(9101, (20, 0), {}), (9102, (24, 0), {})]
        ways.append((8000, [9101, 9102], {"highway": "residential"}))
        rel_members.append(("w", 8000, ""))
    rel_members += [("n", 9001, "stop"), ("n", 9002, "stop")]
    rel = [(5000, rel_members, {"type": "route", "route": "bus", "ref": "1"})]
    return osm_xml(nodes, ways, rel)


def true_route(topo) -> list[tuple[int, int]]:
    """The route as the bus drives it: shortest vehicle paths through its corners (0,1) (3,1) (3,4) (5,4)."""
    from topology.matching import network_graph
    from topology.projection import LocalProjection
    from topology.raw import VEHICLE

    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))
    g = network_graph(topo, VEHICLE)

    def node(i, j):
        xy = proj.to_local(np.array([LON0 + 2 * i * D]), np.array([LAT0 + j * D]))[0]
        return int(np.argmin(np.hypot(*(topo.node_xy - xy).T)))

    corners = [(0, 1), (3, 1), (3, 4), (5, 4)]
    seq: list[int] = []
    for a, b in zip(corners, corners[1:], strict=False):
        p = nx.shortest_path(g, node(*a), node(*b), weight="length")
        seq += p if not seq else p[1:]
    out = []
    for a, b in zip(seq, seq[1:], strict=False):
        k = min(g[a][b], key=lambda k: g[a][b][k]["length"])
        out.append((int(k), 1 if int(topo.edge_nodes[k][0]) == a else -1))
    return out
