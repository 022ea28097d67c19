"""A tram turning back at a terminal triangle stays inside its published cells (issue 20).

The largest share of the vehicles' occupation error in `bench dr` after the look-ahead went from 150 to 40 m
was one tram at the end of its line: it drove down one leg of a terminal triangle, stood at the stop on the
stub, and accelerated up the other leg, which runs within GPS noise of the first for its first 20 m. The
tracker took the fixes for the way back down and the published cells for the wrong leg, and the 40 m cover
ahead no longer reached over the right one, as 150 m had by chance. Here the same geometry (taken from the
Helsinki map, metres) is built as an OSM extract and driven through the client core with 5 m GPS noise
(`sims.bench.dr_bench.run_entity`, 0.5 s samples): the truth's cells must be in the published occupation."""

from __future__ import annotations

import random

import networkx as nx
import numpy as np

from entitynet.client.network import netview
from entitynet.client.path import Path
from sims.bench.dr_bench import _new_acc, run_entity
from sims.bench.dr_data import _sample_path
from sims.mobility import Halts, speed_profile, vehicle_halts
from tests.topology.test_osm_reader import LAT0, osm_xml
from topology.build import build, read_map

M_LON = 1.0 / (111_320.0 * float(np.cos(np.radians(LAT0))))  # degrees a metre east, near LAT0
M_LAT = 1.0 / 111_320.0
D = 0.0009  # osm_xml's unit (degrees)

# the loop, metres east / north: in from the east to A, west to B, south-east down to the apex C, the stub to D,
# back to C2 (beside C), north up to E beside A, and out to the east again
POINTS = {"in": (-200.0, -171.0), "A": (-309.9, -171.7), "B": (-344.5, -165.5), "C": (-319.3, -201.1),
          "D": (-316.4, -205.2), "C2": (-319.1, -200.9), "E": (-311.4, -169.5), "F": (-310.5, -168.7),
          "out": (-200.0, -160.0)}
WAYS = [("in", "A"), ("A", "B"), ("B", "C"), ("C", "D"), ("D", "C2"), ("C2", "E"), ("E", "F"), ("F", "out")]
# as in the city, every corner is a junction (tracks on to the depot and the other lines): a spur from each
SPURS = {"A": (0.0, -30.0), "B": (-30.0, 0.0), "C": (-25.0, -10.0), "D": (0.0, -30.0), "C2": (25.0, -10.0),
         "E": (30.0, -15.0), "F": (0.0, 30.0)}


def _node(name: str) -> int:
    return 100 + list(POINTS).index(name)


def _triangle_osm() -> str:
    nodes = [(_node(n), (x * M_LON / D, y * M_LAT / D), {}) for n, (x, y) in POINTS.items()]
    ways = [(10 + i, [_node(a), _node(b)], {"railway": "tram"}) for i, (a, b) in enumerate(WAYS)]
    for i, (name, (dx, dy)) in enumerate(SPURS.items()):
        x, y = POINTS[name]
        nodes.append((500 + i, ((x + dx) * M_LON / D, (y + dy) * M_LAT / D), {}))
        ways.append((50 + i, [_node(name), 500 + i], {"railway": "tram"}))
    return osm_xml(nodes, ways)


def _drive_path(topo) -> list[tuple[int, int]]:
    """The directed edges of the drive: the tracks form a tree (the loop's corners joined by one way each, the
    spurs dead ends), so the way from "in" to "out" (the two easternmost nodes, "in" the southern) is the loop."""
    from topology.matching import network_graph
    from topology.raw import TRAM

    g = network_graph(topo, TRAM)
    xy = np.asarray(topo.node_xy)
    first, second = (int(k) for k in np.argsort(-xy[:, 0])[:2])
    start, end = (first, second) if xy[first, 1] < xy[second, 1] else (second, first)
    seq = nx.shortest_path(g, start, end, weight="length")
    out = []
    for a, b in zip(seq, seq[1:], strict=False):
        k = min(g[a][b], key=lambda k: g[a][b][k]["length"])
        out.append((int(k), 1 if int(topo.edge_nodes[k][0]) == a else -1))
    return out


def test_tram_turning_back_at_a_terminal_triangle_stays_in_its_published_cells(tmp_path):
    osm = tmp_path / "triangle.osm"
    osm.write_text(_triangle_osm())
    topo = build(read_map(osm))
    net = netview(topo)
    edges = _drive_path(topo)
    truth = Path(net, edges)
    # the stop on the stub: the tram stands there, then accelerates away up the other leg
    k_stub = next(k for k, de in enumerate(edges) if net.edge_len[de[0]] < 8.0)
    stop_s = truth.cum[k_stub + 1]
    acc = _new_acc()
    for seed in range(30):  # bounded: 30 drives of about 60 s each
        rng = random.Random(seed)
        halts = vehicle_halts([stop_s], [], rng, Halts(dwell=(6.0, 12.0), p_red=0.0, red=(0.0, 0.0)))
        prof = speed_profile(truth.length, halts, rng, cruise=9.0, accel=1.0, decel=1.2)
        ent = _sample_path(truth, prof, 27.0, f"tram triangle {seed}", "tram", edges)
        run_entity(topo, ent, "network", 5.0, acc)
    assert acc["occ_n"] > 800
    # measured over these 30 drives: 2.1 % of the time outside with the fixed 40 m look-ahead and the route's
    # other leg not covered (main before issue 20), 0.65 % now; the rest is the aft of the 27 m body behind the
    # stub while the tracker turns: a worst case the city's vehicles meet once an hour (bench dr: 0.01 %)
    assert acc["occ_bad"] / acc["occ_n"] < 0.01, f"{acc['occ_bad']} of {acc['occ_n']} samples outside"
