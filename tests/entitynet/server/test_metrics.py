"""/metrics before anything went wrong: `entitynet_errors_total` has a zero sample for every known error
code from the start, so that rate() and alerts on it work from the first scrape (a series that appears only
with its first error has no previous sample to compare against)."""

from __future__ import annotations

import urllib.request

import trio
from prometheus_client.parser import text_string_to_metric_families

from entitynet import protocol as P
from tests.entitynet.server_helpers import Raw, running


async def _scrape(port: int) -> dict[str, float]:
    body = await trio.to_thread.run_sync(
        lambda: urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5).read().decode())
    [errors] = [f for f in text_string_to_metric_families(body) if f.name == "entitynet_errors"]
    return {s.labels["code"]: s.value for s in errors.samples if s.name == "entitynet_errors_total"}


async def test_every_error_code_has_a_sample_from_the_start():
    async with running(metrics_port=0) as server:
        first = await _scrape(server.metrics_port)
        assert first == {str(int(code)): 0.0 for code in P.ErrorCode}
        c = await Raw.connect(server)
        await c.send(P.Subscribe((10_000,), ()))  # no such cell: 301, the request dropped
        await c.expect(P.Error)
        with trio.fail_after(5):
            while (now := await _scrape(server.metrics_port))[str(int(P.ErrorCode.NO_SUCH_CELL))] != 1.0:
                await trio.sleep(0.05)
        assert sum(now.values()) == 1.0 and set(now) == set(first)
