"""The Player: fixes in, PUBLISH messages out, for the reasons of the reference (section 4.5)."""

import math

import pytest

from entitynet.client import FixRejected, Player, decode, netview
from entitynet.protocol import Publish, Unpublish
from tests.entitynet.client_fixtures import area_square, cross, parallel, tee


def drive(p, xs, y=0.0, t0=0.0, dt=1.0):
    out = []
    for i, x in enumerate(xs):
        out += p.feed(x, y, t0 + i * dt)
    return out


def test_first_fix_publishes_cells_validity_and_a_decodable_payload():
    topo = cross(arm=300.0)
    p = Player(topo, 7, "car")
    (m,) = p.feed(-150.0, 1.0, 0.0)
    assert isinstance(m, Publish) and m.entity == 7 and m.seq == 1
    assert m.cells and m.validity_ms > 0
    g = decode(m.payload, netview(topo))
    assert g.xy_at(0.0) == pytest.approx((-150.0, 0.0), abs=1.5)
    assert p.measured == (-150.0, 1.0, 0.0)
    assert p.inferred[0] == "edge" and p.inferred[1] == 0


def test_constant_motion_without_noise_sends_few_updates():
    p = Player(cross(arm=600.0), 1, "car", threshold=5.0)
    out = drive(p, [-590.0 + 10.0 * i for i in range(50)])
    reasons = p.stats
    assert reasons.get("drift", 0) <= 3, reasons
    assert len(out) < 12  # 50 fixes: first, start, a few settles and validity expiries


def test_stop_and_start_are_emergent_updates():
    p = Player(cross(arm=600.0), 1, "car", threshold=5.0)
    xs = [-590.0 + 10.0 * i for i in range(20)]
    drive(p, xs)
    before = p.stats.get("stop", 0) + p.stats.get("drift", 0)
    drive(p, [xs[-1] + 10.0] * 15, t0=20.0)
    # an abrupt stop is seen first as drift (the filter still has speed) or as a stop; either way the
    # published model ends up standing still where the entity is
    assert p.stats.get("stop", 0) + p.stats.get("drift", 0) > before
    assert p.ghost.speed_at(40.0) == 0.0
    assert p.ghost.xy_at(40.0) == pytest.approx((xs[-1] + 10.0, 0.0), abs=5.0)
    drive(p, [xs[-1] + 10.0 + 10.0 * i for i in range(1, 8)], t0=35.0)
    assert p.stats.get("start", 0) >= 1


def test_turning_at_a_junction_leaves_the_predicted_path():
    topo = tee(arm=300.0)
    p = Player(topo, 1, "car", threshold=5.0)
    drive(p, [-200.0 + 10.0 * i for i in range(20)])  # west -> centre; the rule predicts straight on (east)
    out = []
    for i in range(1, 12):
        out += p.feed(0.0, -10.0 * i, 20.0 + i)  # but it turns south
    assert p.inferred[1] == 2  # on the south edge
    assert p.stats.get("path", 0) + p.stats.get("drift", 0) >= 1
    assert p.path.edges[-1][0] == 2 or (2, 1) in p.path.edges


def test_validity_expiry_republishes_on_tick():
    p = Player(cross(arm=300.0, junction_radius=20.0), 1, "car", threshold=5.0)
    drive(p, [-250.0 + 10.0 * i for i in range(5)])
    exp = p.pub_t + p.occupation.validity
    assert p.tick(exp - 0.01) == []
    (m,) = p.tick(exp)
    assert p.stats["expiry"] >= 1 and m.seq == p.seq


def test_bad_fixes_are_rejected_and_change_nothing():
    p = Player(cross(), 1, "pedestrian")
    p.feed(-50.0, 0.0, 10.0)
    state = (p.seq, p.last_t, p.measured)
    for x, y, t in [(math.nan, 0.0, 11.0), (0.0, math.inf, 11.0), (0.0, 0.0, math.nan), (-49.0, 0.0, 10.0),
                    (-49.0, 0.0, 9.0)]:
        with pytest.raises(FixRejected):
            p.feed(x, y, t)
    with pytest.raises(FixRejected):
        p.feed(-49.0, 0.0, 11.0, accuracy=-1.0)
    assert (p.seq, p.last_t, p.measured) == state


def test_far_from_the_network_publishes_nothing_then_leaves():
    p = Player(cross(arm=100.0), 1, "pedestrian", off_network=60.0, off_network_timeout=10.0)
    assert p.feed(5000.0, 5000.0, 0.0) == []  # never placed: nothing to send
    p.feed(-50.0, 0.0, 1.0)
    assert p.published
    out = []
    for i in range(15):
        out += p.feed(5000.0, 5000.0, 2.0 + i)
    assert out == [Unpublish(1)]


def test_hysteresis_keeps_the_street_under_noise_between_parallel_streets():
    topo = parallel(gap=12.0, length=600.0)
    p = Player(topo, 1, "car", threshold=5.0)
    # on the southern street (y = 0); fixes alternate 5 m north and south: never nearer the other street by 3 m
    for i in range(40):
        p.feed(50.0 + 10.0 * i, 5.0 if i % 2 else -4.0, float(i))
        assert p.inferred[1] == 0


def test_area_entity_publishes_the_area_cell():
    topo = area_square(side=60.0)
    p = Player(topo, 1, "pedestrian")
    (m,) = p.feed(5.0, 5.0, 0.0)
    assert m.cells == (int(topo.area_cell[0]),)
    assert p.inferred[0] == "area"


def test_world_models_without_a_topology():
    p = Player(None, 1, "car", model="fpw", threshold=5.0)
    out = drive(p, [10.0 * i for i in range(30)])
    assert out[0].cells == ()
    assert sum(isinstance(m, Publish) for m in out) < 10
    with pytest.raises(ValueError):
        Player(None, 1, "car", model="network")
    per = Player(None, 1, "car", model="periodic")
    assert len(drive(per, [10.0 * i for i in range(30)])) == 30


def test_the_first_publish_already_reaches_past_its_first_edge():
    topo = cross(arm=300.0)
    p = Player(topo, 1, "car", threshold=5.0)
    (m,) = p.feed(-100.0, 0.0, 0.0)  # on W->C, 100 m before the crossing
    ghost = decode(m.payload, netview(topo))
    assert (1, 1) in ghost.path.edges  # straight on through C to the east arm
    assert m.validity_ms > 1000


def test_a_dead_end_ahead_is_no_reason_to_republish():
    """The model halts at the end of a dead-end path: nothing ahead to enter, so no validity runs out there."""
    topo = cross(arm=300.0)
    p = Player(topo, 1, "car", threshold=5.0)
    t = 0.0
    xs = [150.0 + 10.0 * i for i in range(15)] + [295.0] * 12  # east along C->E to its dead end, then stand
    for x in xs:
        p.feed(x, 0.0, t)
        p.tick(t + 0.5)
        t += 1.0
    assert p.stats.get("expiry", 0) == 0, p.stats
    assert p.occupation.front_period == math.inf
