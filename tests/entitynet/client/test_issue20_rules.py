"""Issue 20's rules, each checked where it acts: a stop where the published model halts by itself is no news,
and the other ways within the lateral cover are listed for a few seconds of travel ahead, not as far as the
occupation reaches (their cells sent a walker's updates to viewers it was not coming to)."""

import math

import pytest

from entitynet.client import NetworkModel, Path, Player, netview
from entitynet.client.coverage import LATERAL_AHEAD_MIN, LATERAL_AHEAD_TIME
from entitynet.client.entities import entity_type
from entitynet.client.kinematics import advance
from entitynet.client.occupation import LOOKAHEAD
from entitynet.client.rules import UpdateRules
from entitynet.protocol import Publish
from tests.entitynet.client_fixtures import cross, make_topology

CELL = 10.0


class _At:
    """An `Estimate` that puts the entity at a given point (the rules' input, without a tracker)."""

    def __init__(self, xy: tuple[float, float]) -> None:
        self.xy = xy

    def position(self, player, t: float) -> tuple[float, float]:
        return self.xy

    def motion(self, player, t: float) -> tuple[float, float]:
        return 0.0, 0.0


def _rules() -> UpdateRules:
    return UpdateRules(entity_type("tram"), periodic=False, threshold=5.0, confirm=1, heartbeat=60.0,
                       max_validity=60.0, period=1.0, max_gap=30.0, lost_after=120.0)


def _ghost(stop_s: float = math.inf) -> NetworkModel:
    """A tram's published model at 8 m/s from x = -500 on the W arm of a cross, halting at `stop_s` (path m)."""
    path = Path(netview(cross(arm=600.0)), [(0, 1), (1, 1)])
    return NetworkModel(0.0, path, 100.0, 8.0, 0.0, 20.0, 3, (30.0,), stop_s, 1.0)


@pytest.mark.parametrize("halt_x", [-400.0, -401.5])
def test_a_tram_standing_where_its_published_model_halts_sends_no_stop(halt_x):
    ghost = _ghost(stop_s=200.0)  # the model halts at x = -400
    t = 5.0  # the model is still braking there (speed > v_stop); the tram already stands at the stop
    assert ghost.speed_at(t) > entity_type("tram").v_stop
    reason = _rules().decide(t, ghost, 0.0, None, 0.0, None, _At((halt_x, 0.0)))
    assert reason != "stop"


def test_a_tram_standing_short_of_where_its_model_halts_sends_its_stop():
    ghost = _ghost(stop_s=200.0)
    reason = _rules().decide(5.0, ghost, 0.0, None, 0.0, None, _At((-440.0, 0.0)))  # a red light 40 m short
    assert reason == "stop"


def test_a_model_without_a_planned_halt_halts_at_its_path_end():
    ghost = _ghost()  # no stop: the model clamps at its path's end (x = 600, the E arm's end)
    rules = _rules()
    assert rules.decide(5.0, ghost, 0.0, None, 0.0, None, _At((-450.0, 0.0))) == "stop"
    far = _ghost()
    far = NetworkModel(0.0, far.path, far.path.length - 30.0, 8.0, 0.0, 20.0, 3, (30.0,))
    assert rules.decide(2.0, far, 0.0, None, 0.0, None, _At((599.0, 0.0))) != "stop"


def _two_footways(gap: float = 6.0) -> object:
    """Two parallel footways `gap` m apart (a sidewalk drawn twice), 400 m long, joined at both ends."""
    nodes = {"A": (0.0, 0.0), "B": (400.0, 0.0), "C": (0.0, gap), "D": (400.0, gap)}
    return make_topology(nodes, [("A", "B", 1), ("C", "D", 1), ("A", "C", 1), ("B", "D", 1)],
                         junction_radius=3.0, street_cell_max=CELL)


def test_the_other_way_is_listed_a_few_seconds_ahead_the_own_way_as_far_as_the_look_ahead():
    topo = _two_footways()
    net = netview(topo)
    p = Player(topo, 1, "pedestrian", threshold=5.0)
    speed = 1.4
    pubs = []
    for i in range(12):
        pubs += [m for m in p.feed(60.0 + speed * i, 0.0, float(i)) if isinstance(m, Publish)]
    assert pubs
    m = pubs[-1]
    x, _y = p.ghost.xy_at(p.ghost.t0)
    b = topo.cell_footprints.bounds()
    other = {c for _a, _b, c in net.pieces(1, 1)}  # the cells of the north footway (edge C-D)
    ahead_other = max(((b[c, 0] + b[c, 2]) / 2.0 - x for c in m.cells if c in other), default=-math.inf)
    ahead_own = max((b[c, 0] + b[c, 2]) / 2.0 - x for c in m.cells if c not in other)
    d, _ = advance(max(p.ghost.v, 0.0), p.ghost.a, entity_type("pedestrian").vmax, LATERAL_AHEAD_TIME)
    reach = p.margin + max(d, LATERAL_AHEAD_MIN)
    assert ahead_other > 0.0, m.cells  # the other way is covered ahead
    assert ahead_other <= reach + CELL, (ahead_other, reach)  # to the cell its reach ends in (its centre)
    assert ahead_own >= p.margin + LOOKAHEAD - CELL, ahead_own  # the own way: the whole look-ahead
    assert ahead_own > ahead_other
