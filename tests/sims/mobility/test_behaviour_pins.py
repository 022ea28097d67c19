"""The mobility model draws the same random numbers in the same order as the three models it replaced.

The digests were recorded on `sims/movers.py`, `sims/behaviours.py` and `sims/bench/dr_bench.py` before they
were merged into `sims.mobility` (issue 10 item 6); together with the switch replay's pin
(tests/sims/bench/test_switch_replay.py) they show that the dr benchmark's truth and the switch benchmark's
load did not change. A deliberate change must update the pin and say why. (The old demo's `Mover` and its pin
went when `entitynet demo` became a preset of the simulation engine, issue 11.)
"""

from __future__ import annotations

import hashlib
import random

import numpy as np

from sims.bench.dr_data import pedestrians
from sims.mobility import KINDS, gps, speed_profile, vehicle_halts


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


def test_one_fix_draws_like_a_track_of_one_point():
    xy = np.array([10.0, -3.0])
    one = gps(xy, np.random.default_rng(9))
    track = gps(xy[None, :], np.random.default_rng(9))
    assert np.array_equal(one, track[0])
    assert not np.array_equal(one, xy)
