"""The dr benchmark's truth reference is injected into the Player (an `Estimate`), not a subclass.

The subclass it replaced overrode private methods and broke silently when one of them gained a parameter
(`estimation_bounds` raised TypeError on every publish since the fix-gap handling).
"""

import numpy as np

from entitynet.client import Player, decode, netview
from sims.bench.dr_bench import SAMPLE, Entity, TruthEstimate, estimation_bounds
from tests.entitynet.client_fixtures import cross


def _straight_car(speed: float = 10.0, seconds: float = 60.0) -> Entity:
    t = np.arange(0.0, seconds, SAMPLE)
    xy = np.column_stack([-250.0 + speed * t, np.zeros_like(t)])
    return Entity("straight car", "car", t, xy, None)


def test_estimation_bounds_run_with_the_truth_injected():
    topo = cross(arm=600.0)
    out = estimation_bounds(topo, [_straight_car()], 5.0)
    assert set(out) == {"true_state_at_publish", "true_position_in_drift_test", "both"}
    assert all(v["updates_per_entity_min"] > 0.0 for v in out.values())


def test_true_state_is_what_a_network_publish_carries():
    topo = cross(arm=600.0)
    ent = _straight_car()
    v_true = np.full(len(ent.t), 7.25)
    truth = (0.0, ent.xy, v_true, np.zeros(len(ent.t)))
    p = Player(topo, 1, "car", threshold=5.0, estimate=TruthEstimate(truth, True, False))
    (pub,) = p.feed(-250.0, 0.0, 0.0)
    assert decode(pub.payload, netview(topo)).v == 7.25  # the filter's own first speed is 0
    assert p.kf.v == 0.0  # the filter goes on with its own estimate
