"""`Subscriptions.apply_limits` reads the limits a real server announces in WELCOME and keeps within them."""

from __future__ import annotations

import math

import pytest

from entitynet.client import LimitExceeded, Subscriptions
from entitynet.protocol import Subscribe
from entitynet.switchboard import SwitchConfig


def test_apply_limits_reads_what_the_switchboard_announces():
    subs = Subscriptions(lambda x, y, z: [])
    subs.apply_limits(SwitchConfig(10, "d", max_subscriptions=3, max_follows=2, query_rate=0.5).wire_limits())
    assert subs.max_subscriptions == 3
    assert subs.max_follows == 2
    assert subs.query_interval == pytest.approx(2.0)  # one query per 1 / query_rate seconds
    subs.query(0.0, identity="bob")
    with pytest.raises(LimitExceeded):
        subs.query(1.9, identity="bob")
    subs.apply_limits(SwitchConfig(10, "d", query_rate=0.0).wire_limits())
    assert subs.query_interval == math.inf


def test_the_cap_keeps_the_first_cells_given_and_trims_after_a_lower_limit():
    pvs = [9, 7, 7, 5, 3, 1]
    subs = Subscriptions(lambda x, y, z: pvs)
    assert subs.move_camera(0.0, 0.0, 2.0) == [Subscribe((1, 3, 5, 7, 9), ())]  # no cap before a WELCOME
    subs.apply_limits({"max_subscriptions": 3})
    assert subs.move_camera(0.0, 0.0, 2.0) == [Subscribe((), (1, 3))]  # duplicates do not use up the cap
    assert subs.cells == {9, 7, 5}
    assert subs.move_camera(1.0, 0.0, 2.0) == []
