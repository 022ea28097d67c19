"""The proxy's vehicles through the one fleet core against the per-vehicle path: the same input (SIRI polls with
and without VehicleLocation, an outage that retires vehicles stale, GTFS-rt positions), the same messages
out of every `tick`, message for message (frozen dataclasses: payload bytes included), and the same counters.

`core="player"` is the per-entity path (one `Player.feed` or `tick` per vehicle and tick, nothing in arrays);
`core="fleet"` decides the usual fix, its Doppler velocity and the timers over arrays. The counters show that
the arrays did carry the fixes, so the equality is not that of two scalar runs.
"""

from __future__ import annotations

import numpy as np
import pytest

import proxies.sim as sim_mod
from entitynet.protocol import Unpublish
from proxies import gtfsrt
from proxies.fleet import MIN_ROWS, Fleet
from proxies.replay_core import ReplayWorld
from proxies.siri_xml import ServiceClock
from topology.projection import LocalProjection


def _recorded(monkeypatch, topo, book, core: str, *, locations=False, outage=None, duration=900.0, min_rows=0):
    """`run_sim`'s replay with the fleet's core `core` (`min_rows` 0: every fix the arrays can take, however
    few in a tick); returns (every tick's messages, the fleet)."""
    got: list[list] = []

    class Recording(Fleet):
        def tick(self, now, **kw):
            before = len(self.pending)  # (what `ingest` left: sent first)
            out = super().tick(now, **kw)
            got.append(out)
            ids = [m.entity for m in out[before:]]
            assert ids == sorted(ids), ids  # the vehicles' own in the order they came (ids grow with it)
            return out

    monkeypatch.setattr(sim_mod, "Fleet", Recording)
    world = ReplayWorld(book.schedule, granularity=60.0, seed=3, locations=locations)
    _res, fleet = sim_mod.run_sim(topo, book, world, start=8 * 3600.0, duration=duration, poll=20.0,
                                  warmup=60.0, outage=outage, fleet_kw={"core": core, "min_rows": min_rows})
    return got, fleet


def _counters(fleet: Fleet) -> tuple:
    c = fleet.counters
    return (c.calls, c.used, c.fixes, c.publishes, c.retired_stale, c.retired_done, fleet.stops_served())


def _same(a, b) -> None:
    assert len(a[0]) == len(b[0])
    for k, (x, y) in enumerate(zip(a[0], b[0], strict=True)):
        assert x == y, f"tick {k}: per vehicle {x} != fleet core {y}"
    assert _counters(a[1]) == _counters(b[1])
    assert sum(len(m) for m in a[0]) > 20


@pytest.mark.parametrize(("locations", "outage", "min_rows"),
                         [(False, None, 0), (True, (300.0, 700.0), 0), (False, None, MIN_ROWS)],
                         ids=["etas", "locations_and_outage", "few_rows_to_the_players"])
def test_the_fleet_core_sends_what_each_player_sends(monkeypatch, line_topo, line_book, locations, outage, min_rows):
    one_by_one = _recorded(monkeypatch, line_topo, line_book, "player", locations=locations, outage=outage)
    fleet = _recorded(monkeypatch, line_topo, line_book, "fleet", locations=locations, outage=outage,
                      min_rows=min_rows)
    _same(one_by_one, fleet)
    c = fleet[1].core.counters
    if min_rows:  # (a few vehicles: their fixes go to the Players, their timers stay in arrays)
        assert c["vector_fixes"] == 0 and fleet[1].core.scalar_why["few_rows"] > 0
        return
    assert c["vector_fixes"] > 0 and c["vector_velocity"] > 0, c  # (the arrays took fixes and their velocity)
    assert one_by_one[1].core.counters["vector_fixes"] == 0
    if outage:
        assert fleet[1].counters.retired_stale > 0  # (vehicles left while others stepped: their order kept)


def test_the_fleet_core_sends_what_each_player_sends_on_the_helsinki_trams(monkeypatch, helsinki, hsl_tram_book):
    """The replayed HSL tram feed over the bundled map (skipped without ../shared)."""
    one_by_one = _recorded(monkeypatch, helsinki, hsl_tram_book, "player", duration=600.0)
    fleet = _recorded(monkeypatch, helsinki, hsl_tram_book, "fleet", duration=600.0)
    _same(one_by_one, fleet)
    assert fleet[1].core.counters["vector_fixes"] > 0


def _positions_run(topo, book, core: str) -> tuple[list, Fleet]:
    """GTFS-rt VehiclePositions every 10 s (each a fix at its own time, to the vehicle's Player directly), the
    motion filling the gaps between them."""
    clock = ServiceClock.for_date(book.schedule.service_date if book.schedule else "20220222")
    proj = LocalProjection(topo.meta["crs"], tuple(topo.meta["origin"]))

    def to_local(lon, lat):
        p = proj.to_local(np.array([lon]), np.array([lat]))[0]
        return float(p[0]), float(p[1])

    world = ReplayWorld(book.schedule, granularity=60.0, seed=4)
    fleet = Fleet(topo, book, core=core, min_rows=0)
    got = []
    for k in range(400):
        t = 8 * 3600.0 + k
        if k % 10 == 0:
            stamp, positions = gtfsrt.parse_vehicle_positions(
                gtfsrt.build_vehicle_positions(world.vehicle_states(t - 1.0), t - 1.0, clock))
            fleet.ingest_positions(positions, 0.0, to_local)
        got.append(fleet.tick(clock.epoch(t), motion_fixes=k % 40 >= 20))
    return got, fleet


def test_positions_fed_directly_and_motion_fixes_agree(line_topo, line_book):
    one_by_one = _positions_run(line_topo, line_book, "player")
    fleet = _positions_run(line_topo, line_book, "fleet")
    assert one_by_one[1].counters.fixes > 20
    _same(one_by_one, fleet)


def test_a_core_other_than_fleet_or_player_is_refused(line_topo, line_book):
    with pytest.raises(ValueError, match="core must be"):
        Fleet(line_topo, line_book, core="arrays")


def _two_vehicles(line_topo, line_book, core: str, stale_after: float) -> list[list]:
    """V1 then V2 on the line; V1 hears nothing after the first poll (stale after `stale_after`), V2 a poll
    every 10 s; a tick every second."""
    from tests.proxies.test_fleet import T0, _call

    fleet = Fleet(line_topo, line_book, stale_after=stale_after, core=core, min_rows=0)
    fleet.ingest([_call(2, T0 + 60.0), _call(3, T0 + 150.0)], T0, T0)
    fleet.ingest([_call(1, T0 + 20.0, vehicle="V2"), _call(2, T0 + 110.0, vehicle="V2")], T0, T0)
    out = []
    for k in range(90):
        if k % 10 == 0:
            fleet.ingest([_call(1, T0 + 20.0, vehicle="V2"), _call(2, T0 + 110.0, vehicle="V2")], T0 + k, T0 + k)
        out.append(fleet.tick(T0 + k))
    return out


def test_a_vehicle_leaving_keeps_its_place_among_the_messages_of_a_tick(line_topo, line_book):
    """V1 goes stale at a tick where V2 publishes: V1's UNPUBLISH comes first (it came first), both ways."""
    free = _two_vehicles(line_topo, line_book, "fleet", 1e9)
    k = next(k for k, msgs in enumerate(free) if k > 40 and any(m.entity == 2 for m in msgs))  # V2 speaks
    got = {core: _two_vehicles(line_topo, line_book, core, k - 0.5) for core in ("player", "fleet")}
    assert got["player"] == got["fleet"]
    tick = got["fleet"][k]
    assert isinstance(tick[0], Unpublish) and tick[0].entity == 1 and any(m.entity == 2 for m in tick), tick
