"""Pedestrian occupation under GPS noise: areas, parallel ways, paths that come back near themselves."""

from __future__ import annotations

import math

from entitynet.client import Player
from tests.entitynet.client_fixtures import area_square, make_topology
from topology.raw import PEDESTRIAN


def two_squares():
    """Two 60 m pedestrian areas side by side (west W1, east E1, touching at x = 0), a street west of W1."""
    west = [(-60.0, -30.0), (0.0, -30.0), (0.0, 30.0), (-60.0, 30.0), (-60.0, -30.0)]
    east = [(0.0, -30.0), (60.0, -30.0), (60.0, 30.0), (0.0, 30.0), (0.0, -30.0)]
    nodes = {"P": (-30.0, 0.0), "Q": (30.0, 0.0), "S": (-160.0, 0.0)}
    return make_topology(nodes, [("S", "P", PEDESTRIAN), ("P", "Q", PEDESTRIAN)],
                         areas=[("P", west, PEDESTRIAN), ("Q", east, PEDESTRIAN)], junction_radius=10.0)


def test_a_fix_just_outside_an_area_with_no_way_near_keeps_the_entity_inside():
    topo = area_square(side=60.0)  # boundary at |x|, |y| = 30; streets leave it west and east along y = 0
    p = Player(topo, 1, "pedestrian")
    for i in range(5):
        p.feed(0.0, 20.0 + i, float(i))
    assert p.mode == "area"
    out = p.feed(0.0, 34.0, 5.0)  # 4 m north of the boundary, the nearest way 34 m away: GPS noise
    assert p.mode == "area" and p.stats.get("path", 0) == 0
    assert all(m.cells[0] == int(topo.area_cell[0]) for m in out)


def test_a_fix_on_a_way_leaving_the_area_leaves_it():
    topo = area_square(side=60.0)
    p = Player(topo, 1, "pedestrian")
    for i in range(5):
        p.feed(-25.0 - i, 0.0, float(i))
    assert p.mode == "area"
    p.feed(-36.0, 0.5, 5.0)  # 6 m out, half a metre from the western street: the street is nearer
    assert p.mode == "edge" and p.stats["path"] == 1


def test_a_fix_far_outside_the_area_leaves_it_even_without_a_nearer_way():
    topo = area_square(side=60.0)
    p = Player(topo, 1, "pedestrian")
    p.feed(0.0, 25.0, 0.0)
    p.feed(0.0, 45.0, 1.0)  # 15 m out: more than 2 x accuracy, not noise
    assert p.mode == "edge"


def test_area_occupation_lists_the_neighbouring_area_and_lasts_until_the_lateral_cover_is_used_up():
    topo = two_squares()
    p = Player(topo, 1, "pedestrian", accuracy=5.0)
    out = []
    for i in range(8):  # walking east at 1.4 m/s, 4 m inside the western area's boundary with the eastern one
        out += p.feed(-12.0 + 1.4 * i, 0.5, float(i))
    assert p.mode == "area" and p.tracker.area == 0
    m = out[-1]
    assert int(topo.area_cell[1]) in m.cells  # 4 m from the other area: GPS cannot tell them apart
    speed = math.hypot(p.ghost.vx, p.ghost.vy)
    assert speed > 0.5
    # every cell within lateral (10 m) is listed: valid until the ghost has moved lateral - accuracy (5 m),
    # not only until it could reach the area's boundary (half a second away here)
    assert p.occupation.validity >= (10.0 - 5.0) / speed - 1e-3


def u_turn(link: float = 8.0):
    """A footway that turns back on itself: A -> B east 20 m, a `link` m link north, C -> D back west."""
    nodes = {"A": (0.0, 0.0), "B": (20.0, 0.0), "C": (20.0, link), "D": (0.0, link), "E": (-60.0, link)}
    return make_topology(nodes, [("A", "B", PEDESTRIAN), ("B", "C", PEDESTRIAN), ("C", "D", PEDESTRIAN),
                                 ("D", "E", PEDESTRIAN)], junction_radius=2.0)


def test_a_fix_nearer_the_path_behind_is_placed_where_the_prediction_is():
    topo = u_turn(link=8.0)
    p = Player(topo, 1, "pedestrian")
    pts = [(float(i), 0.0) for i in range(20)] + [(20.0, float(j)) for j in range(8)]
    pts += [(20.0 - i, 8.0) for i in range(9)]  # on C -> D at x = 12 when t = 36
    for t, (x, y) in enumerate(pts):
        p.feed(x, y, float(t))
    s_before = p.kf.s
    # 4.5 m south of the walker: 3.5 m from A -> B (24 m back along the path), 4.5 m from C -> D
    p.feed(11.0, 3.5, float(len(pts)))
    assert p.inferred[1] == 2  # still on C -> D
    assert p.tracker.last_fix.index == 2
    assert p.kf.s > s_before  # the estimate keeps moving on, not dragged back towards A -> B


def detour():
    """A footway A -> B -> E going east and, from B, a second one turning back west 6 m north of the first
    (B -> (40, 6) -> D): the two run side by side but meet only at B."""
    nodes = {"A": (0.0, 0.0), "B": (40.0, 0.0), "E": (140.0, 0.0), "D": (-60.0, 6.0)}
    return make_topology(nodes, [("A", "B", PEDESTRIAN), ("B", "E", PEDESTRIAN),
                                 ("B", "D", PEDESTRIAN, [(40.0, 6.0)])], junction_radius=2.0)


def test_switching_to_a_side_by_side_way_joined_only_by_a_detour_restarts_there():
    topo = detour()
    p = Player(topo, 1, "pedestrian")
    for i in range(21):  # walking east along A -> B at 1.2 m/s
        p.feed(1.2 * i, 0.0, float(i))
    assert p.inferred[1] == 0 and p.kf.v > 1.0
    # two fixes on the northern way, 6 m away: the walker is there. Joined at B, 16 m ahead, the fix would be
    # 38 m along the path (to B, 6 m north, 16 m back west): not a turn it made, and no speed to learn from
    p.feed(25.2, 6.0, 21.0)
    p.feed(26.4, 6.0, 22.0)
    assert p.inferred[1] == 2
    assert p.stats.get("jump", 0) == 1 and p.stats.get("path", 0) == 0
    assert abs(p.kf.v) < 3.0


def test_the_player_expires_its_occupation_when_the_published_validity_runs_out():
    topo = area_square(side=200.0)
    p = Player(topo, 1, "pedestrian")
    pubs = []
    for i in range(70):  # across a square at 1.3 m/s, zigzagging: periods end at fractions of a millisecond
        for m in p.feed(-80.0 + 1.3 * i, 3.0 * (-1) ** i, float(i)):
            pubs.append((m, p.occupation.validity))
    assert len(pubs) > 3
    for m, validity in pubs:  # the player's own period is the one on the wire, to the millisecond
        assert m.validity_ms / 1000.0 == validity
    # so a tick at the instant the receivers' copy expires re-publishes (it was up to 1 ms late)
    m, validity = pubs[-1]
    t_pub = p.pub_t
    assert p.tick(t_pub + m.validity_ms / 1000.0)


def test_wire_validity_encodes_to_itself_and_never_exceeds_the_period():
    import random

    from entitynet.client.occupation import wire_validity

    rng = random.Random(4)
    for v in [0.5, 1.0003094925868763, 2.0009759138414185, 59.9999] + [rng.uniform(0.5, 60.0) for _ in range(2000)]:
        q = wire_validity(v)
        assert q <= v < q + 0.002
        assert int(q * 1000.0) / 1000.0 == q


def square_by_a_footway(linked: bool):
    """A 60 m pedestrian square (|x|, |y| <= 30) and a footway along its southern side, 3 m outside it
    (y = -33); `linked`: a link from the footway's middle M into the square's node Q."""
    ring = [(-30.0, -30.0), (30.0, -30.0), (30.0, 30.0), (-30.0, 30.0), (-30.0, -30.0)]
    nodes = {"Q": (0.0, 0.0), "A": (-150.0, -33.0), "M": (0.0, -33.0), "B": (150.0, -33.0)}
    edges = [("A", "M", PEDESTRIAN), ("M", "B", PEDESTRIAN)] + ([("M", "Q", PEDESTRIAN)] if linked else [])
    return make_topology(nodes, edges, areas=[("Q", ring, PEDESTRIAN)], junction_radius=5.0)


def test_one_noisy_fix_inside_an_area_beside_the_footway_is_not_an_entry():
    topo = square_by_a_footway(linked=True)
    p = Player(topo, 1, "pedestrian")
    for i in range(40):  # east along the footway, x = -100 .. -53
        p.feed(-100.0 + 1.2 * i, -33.0, float(i))
    for i, y in enumerate([-28.0, -33.5, -27.0, -32.0]):  # x = -28 ..: now and then a fix 3-6 m into the square
        p.feed(-28.0 + 1.2 * i, y, 40.0 + i)
        assert p.mode == "edge"
    assert p.stats.get("path", 0) == 0
    p.feed(-23.0, -27.0, 44.0)
    p.feed(-22.0, -26.0, 45.0)  # two in a row: in the square
    assert p.mode == "area"


def test_a_fix_deep_inside_an_area_enters_it_at_once():
    topo = square_by_a_footway(linked=True)
    p = Player(topo, 1, "pedestrian")
    for i in range(40):
        p.feed(-100.0 + 1.2 * i, -33.0, float(i))
    p.feed(-25.0, -20.0, 40.0)  # 13 m from the footway: GPS noise can do that
    assert p.mode == "edge"
    p.feed(-24.0, -15.0, 41.0)  # 18 m: more than 3 x accuracy, it cannot
    assert p.mode == "area"


def test_fixes_inside_an_area_the_held_way_does_not_lead_to_re_acquire_it():
    topo = square_by_a_footway(linked=False)  # the footway's neighbourhood knows no area
    p = Player(topo, 1, "pedestrian")
    for i in range(30):
        p.feed(-100.0 + 1.2 * i, -33.0, float(i))
    for i in range(10):  # inside the square, 14 m from the footway: held on it, the fixes stay far from it
        p.feed(-20.0 + 1.2 * i, -19.0, 30.0 + i)
    assert p.mode == "area"


def test_a_standing_walker_is_covered_behind_as_well():
    # a straight 300 m footway cut into 5 m street cells
    topo = make_topology({"A": (0.0, 0.0), "B": (300.0, 0.0)}, [("A", "B", PEDESTRIAN)], street_cell_max=5.0)
    net = Player(topo, 1, "pedestrian").net
    p = Player(topo, 1, "pedestrian")
    for i in range(90):  # east at 1.3 m/s to x = 78, then standing there
        p.feed(min(1.3 * i, 78.0), 0.0, float(i))
    assert p.stats.get("stop", 0) >= 1 and p.ghost.v == 0.0
    cells = set(p.occupation.cells)
    # it may turn round: 12 m behind (margin 5 m + lateral 10 m, to a cell boundary) is covered, as ahead
    assert net.cell_at(0, 78.0 - 12.0) in cells
    assert net.cell_at(0, 78.0 + 12.0) in cells
    assert net.cell_at(0, 78.0 - 25.0) not in cells  # and no further than that
