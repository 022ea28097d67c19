"""Routes and OD trips: connected paths, distances, shortest paths on the right network."""

from __future__ import annotations

import random

import pytest

from entitynet.client import netview
from sims.engine.routes import Route, Router
from tests.entitynet.client_fixtures import make_topology
from topology.raw import PEDESTRIAN, VEHICLE


def grid():
    """A 3 x 3 grid of 100 m blocks; the middle row's east-west street is pedestrian only."""
    nodes = {f"{i}{j}": (100.0 * i, 100.0 * j) for i in range(3) for j in range(3)}
    edges = []
    for i in range(3):
        for j in range(3):
            if i < 2:
                edges.append((f"{i}{j}", f"{i + 1}{j}", PEDESTRIAN if j == 1 else PEDESTRIAN | VEHICLE))
            if j < 2:
                edges.append((f"{i}{j}", f"{i}{j + 1}", PEDESTRIAN | VEHICLE))
    return make_topology(nodes, edges)


def test_route_distances_points_and_cells():
    topo = grid()
    net = netview(topo)
    r = Route(net, [(0, 1), (5, 1)])  # 00 -> 10 -> 20
    assert r.length == pytest.approx(200.0)
    x, y = r.xy(150.0)
    assert (x, y) == pytest.approx(net.point(*r.edge_offset(150.0)))
    assert r.xy(50.0, 3.0)[1] == pytest.approx(r.xy(50.0)[1] - 3.0 * r.heading(50.0)[0])
    assert r.cell(10.0) == net.cell_at(*r.edge_offset(10.0))


def test_od_trips_are_connected_shortest_paths_on_their_network():
    topo = grid()
    net = netview(topo)
    router = Router(net, VEHICLE, random.Random(1), pool=9)
    rng = random.Random(2)
    for _ in range(30):
        path = router.trip(rng, min_length=150.0)
        Route(net, path)  # connected, or it raises
        assert all(net.edge_net[e] & VEHICLE for e, _ in path)
        dest = net.end_node(path[-1])
        # after the first edge, the shortest way to the destination
        assert sum(net.edge_len[e] for e, _ in path[1:]) == pytest.approx(router.tree(dest)[net.end_node(path[0])][0])
    # the pedestrian-only street is never used by a car
    ped_only = {e for e in range(net.n_edges) if not net.edge_net[e] & VEHICLE}
    assert ped_only and all(not (set(e for e, _ in router.trip(rng)) & ped_only) for _ in range(20))


def test_trips_never_pass_through_an_area():
    from tests.entitynet.client_fixtures import area_square

    topo = area_square()  # W -> Q (area) -> E: the only way from W to E crosses the square
    net = netview(topo)
    router = Router(net, PEDESTRIAN, random.Random(1), pool=3)
    east = net.edge_to[1]
    assert router.path((0, 1), east) is None  # would cross the square through its centre
    west = net.edge_from[0]
    assert router.path((0, -1), west) == [(0, -1)]
    area = net.edge_to[0]
    assert router.path((0, 1), area) == [(0, 1)]  # to the square itself: fine (the walk inside follows)
