"""zeep on a WSDL (ours, and the CEN one when ../shared is there) against the replay producer over real HTTP:
requests that validate against the CEN XSD, and every fault classified."""

from __future__ import annotations

import time

import pytest
import requests
import trio

from proxies.siri_client import HttpError, StopMonitoringClient, Timeout, Unreachable
from proxies.siri_xml import SiriError, SoapFault, parse_response
from tests.proxies.conftest import CEN_SERVICES_XSD, CEN_WSDL, STOP_X, needs_xsd
from tests.proxies.replay_helpers import make_service, replay_running, url

STOPS = [f"S{i}" for i in range(len(STOP_X))]


def _wsdls():
    out = [None]  # ours
    if CEN_WSDL.exists():
        out.append(str(CEN_WSDL))
    return out


@pytest.mark.parametrize("wsdl", _wsdls(), ids=lambda w: "ours" if w is None else "cen")
@pytest.mark.parametrize("mode", ["multiple", "single"])
async def test_stop_monitoring_over_soap(line_feed, wsdl, mode):
    service = make_service(line_feed)
    seen: list[bytes] = []
    answer = service.answer

    def spy(method, target, body):
        seen.append(body)
        return answer(method, target, body)

    service.answer = spy
    async with replay_running(service):
        client = StopMonitoringClient(url(service), wsdl, mode=mode, timeout=5.0)
        fetched = await trio.to_thread.run_sync(client.fetch, STOPS)
    raws = fetched.answers
    assert not fetched.failures and fetched.not_sent == 0
    assert len(raws) == (1 if mode == "multiple" else len(STOPS)) == client.requests_for(STOPS)
    calls = [c for r in raws for c in parse_response(r).calls]
    assert calls and {c.stop_id for c in calls} <= set(STOPS)
    assert service.state.stops_asked == len(STOPS)
    if CEN_SERVICES_XSD.exists():
        from lxml import etree

        schema = etree.XMLSchema(etree.parse(str(CEN_SERVICES_XSD)))
        for body in seen:
            req = etree.fromstring(body).find("{*}Body")[0]
            assert schema.validate(etree.ElementTree(req)), schema.error_log.filter_from_errors()[:3]


@needs_xsd
def test_zeep_duplicates_request_timestamp_on_the_cen_wsdl_and_the_plugin_strips_them():
    """The known zeep artefact: a plain zeep client on the CEN WSDL emits ServiceRequestInfo with several
    RequestTimestamp elements (invalid); ours (DedupPlugin) emits one, and the message validates."""
    from datetime import UTC, datetime

    import zeep
    from lxml import etree

    schema = etree.XMLSchema(etree.parse(str(CEN_SERVICES_XSD)))
    ours = StopMonitoringClient("http://127.0.0.1:9/siri", str(CEN_WSDL))
    plain = zeep.Client(str(CEN_WSDL))
    when = datetime(2022, 2, 22, 6, 0, tzinfo=UTC)
    req = {"RequestTimestamp": when, "MonitoringRef": "S1", "version": "2.0"}
    counts = []
    for client in (plain, ours.client):
        service = client.create_service(ours.binding, "http://127.0.0.1:9/siri")
        env = client.create_message(service, "GetStopMonitoring", ServiceRequestInfo=ours._info(when), Request=req,
                                    RequestExtension={})
        body = env.find("{*}Body")[0]
        counts.append(len(body.find("ServiceRequestInfo").findall("{*}RequestTimestamp")))
        if client is ours.client:
            assert schema.validate(etree.ElementTree(body)), schema.error_log.filter_from_errors()[:3]
    assert counts[0] > 1 and counts[1] == 1


@pytest.mark.parametrize("fault, exc, match", [
    ("soap", SoapFault, "backend unavailable"),
    ("http500", HttpError, "HTTP 500"),
    ("http503", HttpError, "HTTP 503"),
    ("http404", HttpError, "HTTP 404"),
])
async def test_faults_are_classified(line_feed, fault, exc, match):
    service = make_service(line_feed)
    async with replay_running(service):
        client = StopMonitoringClient(url(service), mode="multiple", timeout=5.0)
        await trio.to_thread.run_sync(requests.post, url(service, f"/control?fault={fault}&count=1"))
        with pytest.raises(exc, match=match):
            await trio.to_thread.run_sync(client.fetch, STOPS)
        # and the next poll works again
        fetched = await trio.to_thread.run_sync(client.fetch, STOPS)
    assert parse_response(fetched.answers[0]).calls


@pytest.mark.parametrize("fault, match", [("garbage", "malformed XML"), ("truncated", "malformed XML")])
async def test_garbage_and_truncated_answers_fail_to_parse(line_feed, fault, match):
    service = make_service(line_feed)
    async with replay_running(service):
        client = StopMonitoringClient(url(service), mode="multiple", timeout=5.0)
        await trio.to_thread.run_sync(requests.post, url(service, f"/control?fault={fault}&count=1"))
        fetched = await trio.to_thread.run_sync(client.fetch, STOPS)
    with pytest.raises(SiriError, match=match):
        parse_response(fetched.answers[0])


async def test_a_slow_service_times_out(line_feed):
    service = make_service(line_feed, slow_s=3.0)
    async with replay_running(service):
        client = StopMonitoringClient(url(service), mode="multiple", timeout=0.5)
        await trio.to_thread.run_sync(requests.post, url(service, "/control?fault=slow&count=1"))
        with pytest.raises(Timeout):
            await trio.to_thread.run_sync(client.fetch, STOPS)


async def test_nobody_listening_is_unreachable(line_feed):
    s = trio.socket.socket()
    await s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # a port with nothing on it
    client = StopMonitoringClient(f"http://127.0.0.1:{port}/siri", mode="multiple", timeout=2.0)
    with pytest.raises(Unreachable):
        await trio.to_thread.run_sync(client.fetch, STOPS)


def test_a_wsdl_without_stop_monitoring_is_refused(tmp_path):
    bad = tmp_path / "x.wsdl"
    bad.write_text('<definitions xmlns="http://schemas.xmlsoap.org/wsdl/" targetNamespace="urn:x"/>')
    with pytest.raises(SiriError, match="GetStopMonitoring"):
        StopMonitoringClient("http://127.0.0.1:9/", str(bad))
    with pytest.raises(SiriError, match="not found"):
        StopMonitoringClient("http://127.0.0.1:9/", str(tmp_path / "missing.wsdl"))


async def test_single_mode_polls_every_stop_and_returns_the_failures(line_feed):
    """One GetStopMonitoring per stop: two failed requests do not end the poll; the other stops are asked and the
    failures come back classified."""
    service = make_service(line_feed)
    async with replay_running(service):
        client = StopMonitoringClient(url(service), mode="single", timeout=5.0)
        await trio.to_thread.run_sync(requests.post, url(service, "/control?fault=http500&count=1"))
        await trio.to_thread.run_sync(requests.post, url(service, "/control?fault=soap&count=1"))
        fetched = await trio.to_thread.run_sync(client.fetch, STOPS)
    assert len(fetched.answers) == len(STOPS) - 2 and fetched.not_sent == 0
    assert [type(e) for e in fetched.failures] == [HttpError, SoapFault]
    assert service.state.stops_asked == len(STOPS) - 2  # the answered ones: every other stop was asked
    assert any(parse_response(raw).calls for raw in fetched.answers)


async def test_a_poll_whose_every_request_fails_raises_the_first_failure(line_feed):
    service = make_service(line_feed)
    async with replay_running(service):
        client = StopMonitoringClient(url(service), mode="single", timeout=5.0)
        await trio.to_thread.run_sync(requests.post, url(service, f"/control?fault=http503&count={len(STOPS)}"))
        with pytest.raises(HttpError, match="HTTP 503"):
            await trio.to_thread.run_sync(client.fetch, STOPS)


async def test_a_poll_stops_asking_once_its_time_is_used_up(line_feed):
    """Timeouts on every stop would make one poll last a timeout per stop: two timeouts into the poll (the default
    deadline) the rest of the poll is not sent (and counted as such)."""
    service = make_service(line_feed, slow_s=3.0)
    async with replay_running(service):
        client = StopMonitoringClient(url(service), mode="single", timeout=0.4)
        await trio.to_thread.run_sync(requests.post, url(service, f"/control?fault=slow&count={len(STOPS)}"))
        with pytest.raises(Timeout):
            await trio.to_thread.run_sync(client.fetch, STOPS)
        # each timeout takes at least 0.4 s: after the second or third (> 0.8 s) the rest were not asked
        assert service.state.faults["slow"] in (2, 3), service.state.faults


async def test_a_poll_sends_nothing_past_its_deadline_and_keeps_its_answers(line_feed):
    """Slow good answers count against the deadline as much as failures: past it nothing more is sent, and the
    answers got so far come back."""
    service = make_service(line_feed, latency=0.3)
    async with replay_running(service):
        client = StopMonitoringClient(url(service), mode="single", timeout=2.0)
        fetched = await trio.to_thread.run_sync(lambda: client.fetch(STOPS, time.monotonic() + 0.45))
    # requests at 0, 0.3 (before the deadline) and 0.6 s (after it: the rest are not sent)
    assert len(fetched.answers) == 2 and not fetched.failures and fetched.not_sent == len(STOPS) - 2
