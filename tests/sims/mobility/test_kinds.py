"""Kinds carry the motion parameters of each entity type, consistent with the client core's types."""

from __future__ import annotations

import random

import pytest

from entitynet.client import entity_type
from sims.mobility import KINDS, kind, profile_for


def test_bodies_and_networks_come_from_the_client_core_types():
    for name, k in KINDS.items():
        et = entity_type(name)
        assert k.networks == et.networks
        assert k.length == float(sum(et.parts))
    assert KINDS["tram"].length == 27.6  # the dr bench's two-part tram
    assert KINDS["car"].length == 4.5  # the switch bench's car body (two cells near a breakpoint)
    assert KINDS["pedestrian"].length == 0.0


def test_transit_kinds_halt_and_others_do_not():
    assert KINDS["bus"].halts is not None and KINDS["tram"].halts is not None
    assert KINDS["bus"].halts.p_red > KINDS["tram"].halts.p_red  # trams have signal priority
    assert KINDS["pedestrian"].halts is None and KINDS["car"].halts is None


def test_unknown_kind_and_missing_profile_parameters_are_clear_errors():
    with pytest.raises(ValueError, match="known: bus, car, pedestrian, tram"):
        kind("hovercraft")
    with pytest.raises(ValueError, match="no acceleration bounds"):
        profile_for(KINDS["car"], 100.0, [], random.Random(1))


def test_a_profile_reaches_the_end_and_respects_the_halts():
    k = KINDS["tram"]
    prof = profile_for(k, 800.0, [(300.0, 20.0)], random.Random(2))
    assert prof.s[-1] == pytest.approx(800.0, abs=0.1)
    v = (prof.s[1:] - prof.s[:-1]) / 0.1
    assert v.max() <= k.cruise * (1 + k.vary * 0.5) + 1e-9
    at_stop = (abs(prof.s - 300.0) < 1e-6).sum() * 0.1
    assert at_stop >= 20.0  # the dwell
