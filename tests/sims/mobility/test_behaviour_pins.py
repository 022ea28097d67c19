"""The mobility model draws the same random numbers in the same order as the three models it replaced.

The digests were recorded on `sims/movers.py`, `sims/behaviours.py` and `sims/bench/dr_bench.py` before they
were merged into `sims.mobility` (issue 10 item 6); together with the switch replay's pin
(tests/sims/bench/test_switch_replay.py) they show that the demo's movers, the dr benchmark's truth and the
switch benchmark's load did not change. A deliberate change must update the pin and say why.
"""

from __future__ import annotations

import hashlib
import random

import numpy as np

from entitynet.client.network import netview
from sims.bench.dr_data import pedestrians
from sims.mobility import KINDS, Mover, gps, speed_profile, vehicle_halts


def test_dr_pedestrian_truth_is_pinned(helsinki):
    h = hashlib.sha256()
    for e in pedestrians(helsinki, 4, random.Random(5)):
        h.update(e.name.encode())
        h.update(e.t.tobytes())
        h.update(e.xy.tobytes())
        h.update(repr([sorted(c) for c in e.cells]).encode())
    assert h.hexdigest() == "9916ad106b72816b3ebfd7a8e9096ce61892374afc376348f47cc5b759314638"


def test_vehicle_halts_and_profile_are_pinned():
    rng = random.Random(3)
    halts = vehicle_halts([150.0, 420.0], [200.0, 300.0, 700.0], rng, KINDS["bus"].halts)
    prof = speed_profile(1000.0, halts, rng, cruise=10.5, accel=1.2, decel=1.5)
    h = hashlib.sha256(repr(halts).encode())
    h.update(prof.t.tobytes())
    h.update(prof.s.tobytes())
    assert h.hexdigest() == "b05bb27f8436a1120a3bfdb30d079fb0ae92714dd3db1d394c982dc58b8c5429"


class _Recorder:
    """Stands in for the Player: records the fixes a mover feeds it (pins the mobility model alone)."""

    def __init__(self) -> None:
        self.got: list[tuple[float, float, float, float]] = []

    def feed(self, x: float, y: float, now: float, accuracy: float) -> list:
        self.got.append((x, y, now, accuracy))
        return []


def test_demo_movers_positions_and_fixes_are_pinned(helsinki):
    net = netview(helsinki)
    rng = random.Random(4)
    movers = [Mover(helsinki, net, i + 1, "car" if rng.random() < 0.3 else "pedestrian", rng) for i in range(20)]
    rec = _Recorder()
    for m in movers:
        m.player = rec
    pos = hashlib.sha256()
    for k in range(60):
        for m in movers:
            m.step(1.0)
            m.fix(100.0 + k)
            pos.update(np.array(m.traj.position()).tobytes())
    assert pos.hexdigest() == "7c625bb2eebc6802edb7ed244363dc56216726e446f831f2c0f5a7897abac687"
    assert hashlib.sha256(np.array(rec.got).tobytes()).hexdigest() == \
        "40f7424687a6b7e7a1ca07d3ea7e9f0d12b5c94f123a9404b2c6266bce760ce1"


def test_one_fix_draws_like_a_track_of_one_point():
    xy = np.array([10.0, -3.0])
    one = gps(xy, np.random.default_rng(9))
    track = gps(xy[None, :], np.random.default_rng(9))
    assert np.array_equal(one, track[0])
    assert not np.array_equal(one, xy)
