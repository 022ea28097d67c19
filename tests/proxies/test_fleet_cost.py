"""What the proxy core spends per vehicle (issue 12's CPU target: 2,000 vehicles on 10 % of a core), counted
rather than timed: client cores built, fixes fed to them, and that the fixes it saves cost no accuracy."""

from __future__ import annotations

import numpy as np

import proxies.fleet as fleet_mod
from proxies.fleet import Fleet
from proxies.replay_core import ReplayWorld
from proxies.sim import run_sim
from proxies.siri_xml import Call

T0 = 1_645_510_000.0


def _call(stop: int, eta: float, *, at=False, etd=None):
    return Call(f"S{stop}", "V1", "1001", "0", "T_east:28800", stop + 1, eta, eta + 20.0 if etd is None else etd,
                None, at, True, None, None)


def test_a_vehicle_not_on_the_map_yet_costs_no_client_core(line_topo, line_book, monkeypatch):
    """A vehicle minutes before its first stop on the map is asked about at every poll; its Player (the
    costliest object of the proxy) is built only once it is placed."""
    built = []
    real = fleet_mod.Player

    def counting(*a, **kw):
        built.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(fleet_mod, "Player", counting)
    fleet = Fleet(line_topo, line_book)
    for k in range(5):
        fleet.ingest([_call(0, T0 + 300.0), _call(1, T0 + 400.0)], T0 + 20.0 * k, T0 + 20.0 * k)
    assert not fleet.vehicles and not built
    fleet.ingest([_call(0, T0 + 110.0), _call(1, T0 + 200.0)], T0 + 100.0, T0 + 100.0)  # 10 s before S0
    assert set(fleet.vehicles) == {"V1"} and len(built) == 1


def test_a_vehicle_standing_at_a_stop_is_not_fed_every_fix_and_its_start_is_fed_at_once(line_topo, line_book):
    fleet = Fleet(line_topo, line_book, granularity=0.0)
    fleet.ingest([_call(2, T0, at=True, etd=T0 + 45.0), _call(3, T0 + 120.0)], T0, T0)
    veh = fleet.vehicles["V1"]
    fed, moving_from = [], None
    for t in range(0, 70):
        before = fleet.counters.fixes
        fleet.tick(T0 + t)
        if fleet.counters.fixes > before:
            fed.append(t)
        if moving_from is None and not veh.motion.standing:
            moving_from = t
    assert moving_from is not None and 40 <= moving_from <= 50
    standing = [t for t in fed if t < moving_from]
    # at 2 s fixes that would be 20 or more; the first few (until the ghost stands), then one every 10 s
    assert len(standing) <= 8, standing
    assert any(moving_from <= t <= moving_from + 2 for t in fed)  # the start goes to the client core at once


def test_fewer_fixes_for_the_same_error(line_topo, line_book):
    """Fixes are fed only where the vehicle is not where its published ghost has it (or stands still), so the
    client cores get a fraction of one fix per `fix_interval`, and the viewers' error stays as it was with
    every fix fed (`quiet_drift=0`)."""
    out = {}
    for q in (0.0, 2.0):
        world = ReplayWorld(line_book.schedule, granularity=60.0)
        res, fleet = run_sim(line_topo, line_book, world, start=8 * 3600.0, duration=900.0, poll=20.0,
                             warmup=60.0, fleet_kw={"quiet_drift": q})
        out[q] = (fleet.counters.fixes, res.vehicle_seconds, float(np.percentile(res.errors, 95)))
    fixes, vs, p95 = out[2.0]
    assert vs > 1000.0
    assert fixes < 0.6 * vs / 2.0  # under 60 % of a fix every 2 s per vehicle
    assert p95 <= out[0.0][2] + 1.5
