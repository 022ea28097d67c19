"""The replay producer as a service: truth over HTTP and on disk, random faults at the asked rate, bad requests."""

from __future__ import annotations

import json

import requests
import trio

from proxies.replay_http import record_truth
from tests.proxies.replay_helpers import make_service, replay_running, url


async def test_truth_endpoint_and_recording(line_feed, tmp_path):
    service = make_service(line_feed)
    out = tmp_path / "truth.jsonl"
    async with replay_running(service):
        r = await trio.to_thread.run_sync(requests.get, url(service, "/truth"))
        doc = r.json()
        assert r.status_code == 200 and doc["vehicles"] and abs(doc["t"] - (8 * 3600 + 600)) < 5
        with trio.move_on_after(1.2):
            await record_truth(service, str(out), every=0.25)
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) >= 3 and all(ln["vehicles"] for ln in lines)
    assert lines[1]["t"] > lines[0]["t"] and lines[0]["epoch"] > 1.6e9
    v = next(iter(lines[0]["vehicles"]))
    lon, lat = lines[0]["vehicles"][v]
    assert 24.0 < lon < 26.0 and 59.0 < lat < 61.0


async def test_random_faults_at_the_rate_asked(line_feed):
    service = make_service(line_feed, fault_rate=0.5, seed=7)
    async with replay_running(service):
        def hammer():
            s = requests.Session()
            return [s.get(url(service, "/gtfs-rt/vehicle-positions"), timeout=5).status_code for _ in range(60)]

        codes = await trio.to_thread.run_sync(hammer)
    faults = sum(service.state.faults.values())
    assert 15 <= faults <= 45 and service.state.requests == 60
    assert "slow" not in service.state.faults  # random faults never hang the caller
    assert any(c >= 400 for c in codes) and any(c == 200 for c in codes)


async def test_bad_requests_get_clear_answers(line_feed):
    service = make_service(line_feed)
    async with replay_running(service):
        def calls():
            return (requests.get(url(service, "/nowhere")).status_code,
                    requests.get(url(service, "/siri")).status_code,
                    requests.post(url(service, "/control?fault=nonsense")).status_code,
                    requests.post(url(service, "/siri"), data=b"not xml"))

        nowhere, get_siri, bad_fault, not_xml = await trio.to_thread.run_sync(calls)
    assert (nowhere, get_siri, bad_fault) == (404, 405, 400)
    assert not_xml.status_code == 500 and b"Fault" in not_xml.content and b"malformed XML" in not_xml.content
