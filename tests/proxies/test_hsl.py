"""The real HSL feed on the bundled Helsinki map (skipped without ../shared): the trams' routes, answers that
validate against the CEN XSD with real stop and trip codes, and the whole chain's accuracy against the truth."""

from __future__ import annotations

import pytest

from proxies.replay_core import ReplayWorld
from proxies.sim import run_sim
from tests.proxies.conftest import CEN_SERVICES_XSD, needs_feed

pytestmark = needs_feed


def test_tram_trips_get_routes_and_stops_over_the_map(hsl_tram_book):
    book = hsl_tram_book
    assert len(book.routes) > 50 and len(book.stops) > 10
    for r in {id(r): r for r in book.routes.values()}.values():
        s = [st.s for st in r.stops]
        assert s == sorted(s) and 0.0 <= s[0] and s[-1] <= r.length + 1e-6
        assert [st.index for st in r.stops] == sorted({st.index for st in r.stops})
    # a journey reference (an NMTOKEN with the run's start) finds its trip
    dep = next(d for d in book.schedule.departures if d.pattern.trip_id in book.routes)
    assert book.route_of(dep.journey)[0] == dep.pattern.trip_id


@pytest.mark.skipif(not CEN_SERVICES_XSD.exists(), reason="../shared/siri/xsd absent")
def test_answers_with_real_codes_validate(hsl_tram_book):
    from lxml import etree

    from proxies.siri_xml import ServiceClock, build_response

    world = ReplayWorld(hsl_tram_book.schedule, locations=True)
    now = 8 * 3600 + 900.0
    visits = world.visits(hsl_tram_book.stops, now)
    assert len(visits) > 20
    env = etree.fromstring(build_response(visits, now, ServiceClock.for_date("20220222"),
                                          operation="GetMultipleStopMonitoring"))
    schema = etree.XMLSchema(etree.parse(str(CEN_SERVICES_XSD)))
    assert schema.validate(etree.ElementTree(env.find("{*}Body")[0])), schema.error_log.filter_from_errors()[:3]


@pytest.mark.parametrize("granularity, p95_max", [(1.0, 30.0), (60.0, 150.0)])
def test_proxied_trams_follow_the_truth(helsinki, hsl_tram_book, granularity, p95_max):
    """Replay -> SIRI XML -> fleet -> published model, in virtual time, 20 s polls with 3 s latency."""
    world = ReplayWorld(hsl_tram_book.schedule, granularity=granularity)
    res, fleet = run_sim(helsinki, hsl_tram_book, world, start=8 * 3600, duration=360.0, poll=20.0, latency=3.0,
                         warmup=60.0)
    summary = res.summary()
    assert summary["vehicles_traced"] >= 5 and summary["position_error_m"]["samples"] > 500
    assert summary["position_error_m"]["p95"] <= p95_max, summary
    assert res.lost == 0
    assert fleet.counters.discarded_fraction > 0.3  # a stop sees the same vehicle many times over
