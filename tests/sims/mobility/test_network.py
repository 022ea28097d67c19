"""Trajectories stay on their kind's networks, grow ahead and are trimmed behind."""

from __future__ import annotations

import math
import random

import pytest

from entitynet.client.network import netview
from sims.mobility import KINDS, Trajectory, random_start, random_walk


def test_trajectory_advances_on_its_network_with_a_bounded_path(helsinki):
    net = netview(helsinki)
    rng = random.Random(1)
    nets = KINDS["car"].networks
    traj = Trajectory.starting_at(net, nets, rng, random_start(net, nets, rng))
    prev = traj.position()
    moved = 0.0
    for _ in range(300):
        traj.advance(8.0)
        x, y = traj.position()
        moved += math.dist(prev, (x, y))
        prev = (x, y)
        assert all(net.edge_net[e] & nets for e, _d in traj.path)
        assert len(traj.path) <= 3  # trimmed behind: an 8 m step never needs more edges than that here
    assert moved > 300.0  # it went somewhere (straight-line steps undercount turns, never overcount)
    traj.advance(-5.0)  # a negative step does not move it back
    assert traj.position() == prev


def test_random_walk_is_a_connected_path_of_about_the_length(helsinki):
    net = netview(helsinki)
    rng = random.Random(2)
    nets = KINDS["pedestrian"].networks
    edges = random_walk(net, random_start(net, nets, rng), nets, 400.0, rng)
    for a, b in zip(edges, edges[1:], strict=False):
        assert net.end_node(a) == net.start_node(b)
    assert sum(net.edge_len[e] for e, _ in edges) <= 400.0 + max(net.edge_len)


def test_no_start_on_a_network_the_map_lacks(helsinki):
    net = netview(helsinki)
    with pytest.raises(ValueError, match="no edge"):
        random_start(net, 0, random.Random(1))
