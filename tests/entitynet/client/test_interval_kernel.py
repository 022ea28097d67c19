"""The fleet core's interval kernel (`fleet_kernels.interval_rows`) against the rules it writes out
(`UpdateRules.note_interval`, `usual_interval`, `gap_limit`): the same kept intervals and the same gap limit
after every fix, for any sequence of intervals (holes, zeros, losses and times running backwards included)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from entitynet.client.entities import entity_type
from entitynet.client.fleet_kernels import interval_rows
from entitynet.client.rules import FIX_INTERVALS_KEPT, GAP_INTERVALS, MIN_INTERVALS, UpdateRules

DT = st.one_of(st.floats(0.05, 40.0), st.sampled_from([0.0, -1.0, 180.0, 400.0]), st.floats(0.9, 1.1))


@settings(max_examples=150, deadline=None)
@given(st.lists(DT, min_size=1, max_size=20), st.sampled_from(["bus", "pedestrian", "car"]))
def test_the_kernel_keeps_what_the_rules_keep(dts, kind):
    et = entity_type(kind)
    rules = UpdateRules(et, periodic=False, threshold=5.0, confirm=1, heartbeat=60.0, max_validity=60.0,
                        period=1.0, max_gap=et.max_gap, lost_after=et.lost_after)
    ring = np.zeros((1, FIX_INTERVALS_KEPT))
    n = np.zeros(1, dtype=np.int64)
    one = np.ones(1)
    for dt in dts:
        rules.note_interval(dt)
        ring, n, gap, reach, usual = interval_rows(ring, n, np.array([dt]), et.max_gap * one, et.lost_after * one,
                                            40.0 * one, et.vmax * one, GAP_INTERVALS, MIN_INTERVALS)
        kept = ring[0, FIX_INTERVALS_KEPT - int(n[0]):].tolist() if n[0] else []
        assert kept == rules.intervals
        assert gap[0] == rules.gap_limit
        assert reach[0] == max(40.0, et.vmax * rules.interval)  # NetworkTracker.follow_cadence (interval 0: none)
