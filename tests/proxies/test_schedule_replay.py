"""The GTFS schedule (frequencies expanded) and the replay producer's simulated world."""

from __future__ import annotations

import numpy as np
import pytest

from proxies.replay_core import ReplayWorld, _profile_distance, min_run_time
from proxies.schedule import nmtoken, read_schedule
from tests.proxies.conftest import CEN_SERVICES_XSD, STOP_X, needs_xsd
from topology.gtfs import parse_time


def test_frequencies_expand_into_departures_every_headway(line_feed):
    sched = read_schedule(line_feed, modes=("tram",))
    east = [d for d in sched.departures if d.pattern.trip_id == "T east"]
    assert [d.start for d in east] == list(range(parse_time("07:50:00"), parse_time("09:00:00"), 300))
    assert len({d.journey for d in sched.departures}) == len(sched.departures) == 2 * len(east)
    assert east[0].journey == "T_east:28200"  # an NMTOKEN: no spaces
    pat = east[0].pattern
    assert np.all(np.diff(pat.stop_dist) > 350.0) and pat.arr[-1] == 5 * 90
    # a window keeps only the departures running in it
    some = read_schedule(line_feed, modes=("tram",), window=(8 * 3600 + 1800, 8 * 3600 + 1900))
    assert 0 < len(some.departures) < len(sched.departures)


def test_nmtoken_keeps_codes_readable():
    assert nmtoken("1001 5_20220204_Ti_1_0652") == "1001_5_20220204_Ti_1_0652"
    assert nmtoken("a:b@c") == "a_b_c"


def test_profile_covers_the_run_exactly_and_never_goes_back():
    L, T = 400.0, 60.0
    ds = [_profile_distance(L, T, t) for t in np.linspace(0.0, T, 121)]
    assert ds[0] == 0.0 and ds[-1] == pytest.approx(L)
    assert np.all(np.diff(ds) >= -1e-9)
    assert min_run_time(400.0, 14.0) < T


def test_replay_vehicles_run_late_or_early_and_report_minute_etas(line_feed):
    sched = read_schedule(line_feed, modes=("tram",))
    world = ReplayWorld(sched, seed=3, delay_sigma=60.0)
    delays = [r.delay_at[0] for r in world.runs]
    assert min(delays) < -5.0 and max(delays) > 5.0  # some early, some late
    now = 8 * 3600 + 600.0
    visits = world.visits([f"S{i}" for i in range(len(STOP_X))], now)
    assert visits and all(v.expected_arrival % 60.0 == 0.0 for v in visits)
    assert all(v.vehicle.startswith("T") and v.monitored for v in visits)  # trams are all traced
    for v in visits:
        run = next(r for r in world.runs if r.vehicle == v.vehicle)
        _d, last, _at = run.distance(now)
        if now >= run.begin and v.order - 1 == last + 1:  # the next stop: its true arrival, to the minute
            assert abs(v.expected_arrival - run.arr_t[v.order - 1]) <= 30.0
    # truth: every vehicle moves forward along its line
    for run in world.runs[:5]:
        d = [run.distance(t)[0] for t in np.arange(run.begin, run.end, 5.0)]
        assert np.all(np.diff(d) >= -1e-6)


def test_untraced_buses_have_no_vehicle_ref(line_feed):
    sched = read_schedule(line_feed, modes=("tram",))
    sched.routes = {k: ("bus", n) for k, (_m, n) in sched.routes.items()}
    world = ReplayWorld(sched, traced_bus_fraction=0.3)
    visits = world.visits(["S2"], 8 * 3600 + 900.0)
    assert any(not v.vehicle and not v.monitored for v in visits)
    assert any(v.vehicle for v in visits)


@needs_xsd
def test_replay_answers_validate_against_the_cen_xsd(line_feed):
    from lxml import etree

    from proxies.siri_xml import ServiceClock, build_response

    schema = etree.XMLSchema(etree.parse(str(CEN_SERVICES_XSD)))
    sched = read_schedule(line_feed, modes=("tram",))
    world = ReplayWorld(sched, locations=True)
    now = 8 * 3600 + 700.0
    visits = world.visits([f"S{i}" for i in range(6)], now)
    assert any(v.at_stop for v in visits) or visits
    for op in ("GetStopMonitoring", "GetMultipleStopMonitoring"):
        env = etree.fromstring(build_response(visits, now, ServiceClock.for_date("20220222"), operation=op))
        body = env.find("{*}Body")[0]
        assert schema.validate(etree.ElementTree(body)), schema.error_log.filter_from_errors()[:3]
