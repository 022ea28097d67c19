"""Placement: first fix, continuity, determinism on vertices and equidistant edges, hairpins."""

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
