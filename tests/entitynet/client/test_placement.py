"""Placement: first fix, continuity, determinism on vertices and equidistant edges, hairpins."""

import numpy as np
import pytest

from entitynet.client import Player, netview
from entitynet.client.placement import Placer
from tests.entitynet.client_fixtures import cross, hairpin, parallel
from topology.raw import PEDESTRIAN, VEHICLE


def test_projection_exactly_on_a_vertex_and_equidistant_edges_is_deterministic():
    topo = cross(arm=100.0)
    pl = Placer(netview(topo), VEHICLE)
    a = [pl.near(0.0, 0.0, 0, set())[0] for _ in range(3)]  # exactly on the crossing node
    assert a[0] == a[1] == a[2] and a[0].index == 0 and a[0].offset == 100.0  # lowest edge id wins
    b = pl.near(5.0, 5.0, 0, set())[0]  # equidistant to the east and north arms
    assert b.index == 1 and b.distance == 5.0
    assert pl.first(5.0, 5.0).index == pl.first(5.0, 5.0).index


def test_first_fix_uses_the_placement_index():
    topo = cross(arm=100.0)
    f = Placer(netview(topo), PEDESTRIAN).first(-40.0, 3.0)
    assert f.kind == "edge" and f.index == 0 and abs(f.offset - 60.0) < 1e-9 and abs(f.distance - 3.0) < 1e-9


def test_hairpin_stays_on_its_leg():
    topo = hairpin(length=100.0, gap=4.0)  # one edge: out along y = 0, back along y = 4
    p = Player(topo, 1, "pedestrian", threshold=5.0)
    for i in range(60):
        p.feed(1.0 + 1.5 * i, 1.5 if i % 2 else 0.5, float(i))  # walking out, fixes nearer the outward leg
    off = p.inferred[2]
    assert off < 100.0  # still on the outward leg, not flipped to the return leg (offset > 104)


def test_a_clear_switch_to_the_parallel_street_happens_after_the_hysteresis():
    topo = parallel(gap=30.0, length=600.0)
    p = Player(topo, 1, "car", threshold=5.0)
    for i in range(10):
        p.feed(50.0 + 10.0 * i, 0.0, float(i))
    assert p.inferred[1] == 0
    for i in range(10, 20):  # now clearly on the northern street
        p.feed(50.0 + 10.0 * i, 30.0, float(i))
    assert p.inferred[1] == 1


def test_a_bounded_placer_drops_the_least_recently_used_table_and_answers_alike(helsinki):
    """`tables_kept` bounds the segment tables (least recently used dropped); a dropped table is built again
    and every answer is the unbounded placer's, bit for bit, along a walk that comes back to its edges."""
    net = netview(helsinki)
    small, full = Placer(net, PEDESTRIAN, tables_kept=3), Placer(net, PEDESTRIAN)
    rng = np.random.default_rng(3)
    edges = [int(e) for e in rng.choice(net.n_edges, 6, replace=False)]
    for e in edges[:4]:
        small.table(e)
    assert list(small._tables) == edges[1:4]  # the first dropped
    small.table(edges[1])  # used again: now the most recent
    small.table(edges[4])
    assert list(small._tables) == [edges[3], edges[1], edges[4]]
    for _ in range(3):  # come back to every edge: rebuilt tables answer as the kept ones do
        for e in edges:
            x, y = net.gx[net.geom_off[e]] + rng.normal(0.0, 5.0), net.gy[net.geom_off[e]] + rng.normal(0.0, 5.0)
            assert small.near(x, y, e, {e}, 3.0) == full.near(x, y, e, {e}, 3.0)
            assert small.on_edges(x, y, edges[:3]) == full.on_edges(x, y, edges[:3])
            assert len(small._tables) <= 3
    with pytest.raises(ValueError, match="at least one"):
        Placer(net, PEDESTRIAN, tables_kept=0)


def test_route_tables_are_keyed_by_their_edges_not_a_hash(helsinki):
    """`on_edges` keys its table by the edge set itself: two sets never share one, and an edge's own
    neighbourhood table is never taken for a route's."""
    net = netview(helsinki)
    pl = Placer(net, PEDESTRIAN)
    pl.table(5)
    f = pl.on_edges(0.0, 0.0, [5])
    assert ("route", (5,)) in pl._tables and 5 in pl._tables
    assert pl._tables[("route", (5,))].edges == [5] and f.index == 5
