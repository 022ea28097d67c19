"""The publish's caches (issue 11): each gives exactly what computing afresh gives, searches only where it
must, and belongs to its own topology (two maps with the same edges and different cells never share)."""

import random

import numpy as np
import pytest

from entitynet.client import netview
from entitynet.client import occupation as occmod
from entitynet.client.coverage import _way_back
from entitynet.client.lateral import near_index
from entitynet.client.occupation import _branch_cover, branch_cover, certain_end, occupy
from entitynet.client.path import Path, follow
from entitynet.client.placement import Placer, ring_distance
from entitynet.client.tracker import MAX_PATH_EDGES
from tests.entitynet.client_fixtures import area_square, chain, cross, parallel
from topology.raw import PEDESTRIAN, VEHICLE


def _certain_end_reference(path: Path, s_front: float, networks: int, known_until: float) -> float:
    """`certain_end` as written before its per-(edge, cell) allowance memo."""
    net = path.net
    k = occmod._first_choice(path, s_front, networks, known_until)
    if k < 0:
        return path.length
    de = path.edges[k]
    s_node = path.cum[k + 1]
    node_cell = path.cell(s_node - 1e-9) if s_node > 0 else path.cell(0.0)
    allowance = float("inf")
    for cand in net.choices(de, networks):
        a0, b0, c0 = net.pieces(*cand)[0]
        allowance = min(allowance, b0 if c0 == node_cell else 0.0)
    if not net.choices(de, networks):
        allowance = 0.0
    return min(s_node + allowance, path.length)


def _two_maps():
    """The same X crossing twice: whole street cells, and street cells cut every 15 m (same edges, other
    cells), each with its own view."""
    return netview(cross(arm=100.0)), netview(cross(arm=100.0, street_cell_max=15.0))


def test_branch_cover_memo_equals_the_search_for_any_depth_order():
    rng = random.Random(7)
    for net in _two_maps():
        for de in [(0, 1), (2, 1), (1, -1), (3, -1)]:
            path = Path(net, [de])
            depths = [rng.uniform(-5.0, 250.0) for _ in range(300)] + [0.0, 20.0, 40.0, 80.0, 80.0 + 1e-12]
            rng.shuffle(depths)
            for depth in depths:
                for budget in ((48, 64), (3, 64), (48, 2)):
                    got = branch_cover(path, 0, depth, VEHICLE, *budget)
                    assert got == _branch_cover(net, de, depth, VEHICLE, *budget), (de, depth, budget)


def test_branch_cover_memo_searches_once_per_interval(monkeypatch):
    """Depths that the search cannot tell apart are one memo entry: a publish without a route asks with a
    fresh float each time and must not search each time (it did before the interval memo)."""
    net = netview(cross(arm=100.0, street_cell_max=15.0))
    net.__dict__.pop("_branch_cover", None)
    calls = []
    name = "_span" if hasattr(occmod, "_span") else "_branch_cover"
    real = getattr(occmod, name)

    def counting(*args):
        calls.append(args[2])
        return real(*args)

    monkeypatch.setattr(occmod, name, counting)
    path = Path(net, [(0, 1)])
    for i in range(50):
        branch_cover(path, 0, 41.0 + i * 0.01, VEHICLE)  # no cell boundary of the tree in [41, 41.5)
    assert len(calls) == 1


def test_allowance_memo_is_per_map_and_exact():
    a, b = _two_maps()
    rng = random.Random(3)
    for _round in range(2):  # the second round answers from the memos: still each map's own answer
        for net in (a, b):
            for edges in ([(0, 1), (1, 1)], [(2, 1), (3, 1)], [(1, -1), (0, -1)], [(0, 1)]):
                path = Path(net, edges)
                for _ in range(40):
                    s = rng.uniform(0.0, path.length)
                    known = rng.choice([0.0, s, path.length])
                    assert certain_end(path, s, VEHICLE, known) == _certain_end_reference(path, s, VEHICLE, known)


def test_occupy_on_two_maps_with_the_same_edges_keeps_each_maps_cells():
    """Interleaved publishes on two maps that differ only in one way's cells: each answer is its own map's
    (what a fresh view, with no memo at all, computes)."""
    a, b = _two_maps()
    fresh_a, fresh_b = netview(cross(arm=100.0)), netview(cross(arm=100.0, street_cell_max=15.0))
    rng = random.Random(1)
    for _ in range(60):
        s, la, v = rng.uniform(0.0, 100.0), rng.choice([0.0, 40.0, 150.0]), rng.uniform(0.0, 14.0)
        for net, fresh in ((a, fresh_a), (b, fresh_b)):
            got = occupy(Path(net, [(0, 1)]), s, 4.0, v, 0.0, 14.0, VEHICLE, margin=5.0, lookahead=la)
            for key in ("_branch_cover", "_allowance"):
                fresh.__dict__.pop(key, None)
            want = occupy(Path(fresh, [(0, 1)]), s, 4.0, v, 0.0, 14.0, VEHICLE, margin=5.0, lookahead=la)
            assert got == want
    long_a = occupy(Path(a, [(0, 1)]), 60.0, 0.0, 5.0, 0.0, 14.0, VEHICLE, margin=5.0, lookahead=200.0)
    long_b = occupy(Path(b, [(0, 1)]), 60.0, 0.0, 5.0, 0.0, 14.0, VEHICLE, margin=5.0, lookahead=200.0)
    assert len(long_b.cells) > len(long_a.cells)  # the cut map lists more cells along the same ways


def test_way_back_is_the_followed_path_built_once_per_map():
    for net in _two_maps():
        for back in [(0, -1), (1, 1), (2, -1), (3, 1)]:
            want = Path(net, [back] + follow(net, back, VEHICLE, 125.0, max_edges=MAX_PATH_EDGES))
            got = _way_back(net, back, VEHICLE, 125.0)
            assert got == want and got.cum == want.cum
            assert _way_back(net, back, VEHICLE, 125.0) is got  # built once
    a, b = _two_maps()
    assert _way_back(a, (0, -1), VEHICLE, 125.0).net is a and _way_back(b, (0, -1), VEHICLE, 125.0).net is b


@pytest.mark.parametrize("topo", [cross(arm=100.0), parallel(gap=12.0, length=300.0), chain(), area_square()])
def test_near_index_edges_near_equals_the_placers(topo):
    net = netview(topo)
    rng = random.Random(11)
    for networks in (VEHICLE, PEDESTRIAN):
        placer = Placer(net, networks)
        idx = near_index(placer)
        pts = [(rng.uniform(-260.0, 360.0), rng.uniform(-150.0, 150.0)) for _ in range(400)]
        pts += [(50.0 * i + d, 50.0 * j - d) for i in range(-3, 4) for j in range(-3, 4) for d in (0.0, 1e-9, 9.99)]
        for x, y in pts:
            for r in (0.5, 10.0, 30.0, 70.0):
                assert idx.edges_near(x, y, r) == placer.edges_near(x, y, r), (x, y, r)


def test_near_index_within_ring_equals_ring_distance_also_at_the_boundary():
    net = netview(area_square(side=60.0))
    placer = Placer(net, PEDESTRIAN)
    idx = near_index(placer)
    ring = placer.ring(0)
    rng = random.Random(5)
    pts = [(rng.uniform(-60.0, 60.0), rng.uniform(-60.0, 60.0)) for _ in range(500)]
    pts += [(40.0, 0.0), (30.0 + 10.0, 5.0), (0.0, -40.0), (37.0, 37.0)]  # exactly 10 m out, and a corner
    for x, y in pts:
        d = ring_distance(ring, x, y)
        for r in (d, np.nextafter(d, 0.0), np.nextafter(d, np.inf), 10.0, 0.5, 25.0):
            assert idx.within_ring(0, x, y, float(r)) == (d <= r), (x, y, r)


def test_branch_cover_memo_keeps_its_keys_up_to_its_bound():
    """The memo starts afresh only past BRANCH_MEMO_KEYS keys (at 4,096 it was cleared every few minutes in the
    city simulation, issue 22), and then it does, so that it stays bounded."""
    net = netview(cross(arm=100.0))
    cache = net.__dict__.setdefault("_branch_cover", {})
    cache.clear()
    cache.update({("other", i): ([], []) for i in range(occmod.BRANCH_MEMO_KEYS)})
    branch_cover(Path(net, [(0, 1)]), 0, 10.0, VEHICLE)
    assert len(cache) == occmod.BRANCH_MEMO_KEYS + 1  # kept, and the new key added
    got = branch_cover(Path(net, [(2, 1)]), 0, 10.0, VEHICLE)
    assert len(cache) == 1 and got == _branch_cover(net, (2, 1), 10.0, VEHICLE, 48, 64)
