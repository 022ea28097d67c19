"""The browser viewer in a real headless Chromium against a live demo (the sim preset) on loopback.

Skips when no Chromium is installed or the page's bundle was not built (`npm ci && npm run build`); `.ci/run`
installs both, so in CI it runs. Checks: the WebGL canvas has drawn (non-background pixels, entity colours),
the page holds exactly the entities the server sent it (the server's own record of who knows which entity), a
camera move sends one SUBSCRIBE difference whose cells are the Python lookup's for that position, and a
screenshot is saved under the test's output folder.
"""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
import trio

from entitynet import protocol as P
from entitynet.viewer.routes import BUNDLE, STATIC
from sims.browser import find_chromium, open_chromium
from sims.demo import DemoConfig, run_demo
from sims.engine.viewers import radius_cells_at
from tests.sims.test_demo import _one_tram

pytestmark = [
    pytest.mark.skipif(find_chromium() is None, reason="no Chromium installed (apt-get install chromium)"),
    pytest.mark.skipif(not (STATIC / BUNDLE).exists(), reason="viewer bundle not built (npm ci && npm run build)"),
]

BACKGROUND = np.array([28, 31, 38])  # the page's background (style.css), where WebGL drew nothing


def _server_view(server, cid: int) -> set[int]:
    """The entities the server has sent this client and not withdrawn (its own table of who knows whom)."""
    return {e.eid for e in server.sb.entities.values() if cid in e.viewers}


def _png(data: bytes) -> np.ndarray:
    import matplotlib.image as mpimg

    return (mpimg.imread(io.BytesIO(data), format="png")[:, :, :3] * 255).round().astype(int)


async def test_viewer_in_headless_chromium(helsinki, helsinki_path, tmp_path):
    config = DemoConfig(entities=120, viewers=0, connections=2, duration=60.0, summary_every=1000.0, seed=5,
                        http_port=0)
    subscribes: list[P.Subscribe] = []
    async with trio.open_nursery() as nursery:
        server = await nursery.start(run_demo, helsinki, helsinki_path, config, lambda m: None, _one_tram(helsinki))
        receive = server.sb.receive

        def counting_receive(cid, msgs, now, frame_end=True):  # count the page's SUBSCRIBEs as the core sees them
            if server.conns.get(cid) is not None and server.conns[cid].kind == "ws":
                subscribes.extend(m for m in msgs if isinstance(m, P.Subscribe))
            return receive(cid, msgs, now, frame_end)

        server.sb.receive = counting_receive
        url = f"http://127.0.0.1:{server.http_port}/"
        async with open_chromium(width=1024, height=640) as page:
            opened = time.perf_counter()
            await page.goto(url)
            await page.wait_for("window.entitynet && window.entitynet.stats && window.entitynet.stats().held > 0",
                                timeout=60)
            first_entity_s = time.perf_counter() - opened
            stats = await page.evaluate("window.entitynet.stats()")
            assert stats["error"] is None and stats["badPayloads"] == 0, stats
            # the page extrapolates in the publishers' time: the simulation's clock, which the in-process server
            # runs on and reports in WELCOME / PONG (a page on another clock would extrapolate by hours). That clock
            # runs at most one tick past the last tick (`Shell.clock`): while a tick is late it stands, so a page
            # that synced then is up to a tick behind the next tick's publishes (seen once in CI on a busy machine:
            # t - t0 = -0.31 s at 2 Hz)
            tick = 1.0 / config.tick_hz
            for p in await page.evaluate("window.entitynet.positions(20)"):
                assert -tick <= p["t"] - p["t0"] < 30.0, p
            ws = [c for c in server.conns.values() if c.kind == "ws"]
            assert len(ws) == 1
            cid = ws[0].cid

            # the page holds what the server sent it: compare at a quiet moment (publishes come once a second)
            for _ in range(50):
                before = _server_view(server, cid)
                ids = set(await page.evaluate("window.entitynet.entityIds()"))
                if ids == before == _server_view(server, cid):
                    break
                await trio.sleep(0.1)
            assert ids == _server_view(server, cid) and len(ids) > 0, (len(ids), len(_server_view(server, cid)))

            # the subscription is the Python lookup's for the camera (no PVS in this artifact: 500 m cut)
            cells_at = radius_cells_at(helsinki)
            x, y, z = await page.evaluate("window.entitynet.camera()")
            assert await page.evaluate("window.entitynet.subscribedCells()") == sorted(map(int, cells_at(x, y, z)))
            assert server.sb.clients[cid].subs == set(map(int, cells_at(x, y, z)))

            # one camera move -> exactly one SUBSCRIBE difference
            n_before = len(subscribes)
            sent_before = (await page.evaluate("window.entitynet.stats()"))["subscribesSent"]
            x2, y2 = x + 450.0, y + 700.0
            want = set(map(int, cells_at(x2, y2, z)))
            assert want != server.sb.clients[cid].subs
            await page.evaluate(f"window.entitynet.setCamera({x2}, {y2}, {z})")
            with trio.fail_after(30):  # (a condition's deadline, generous for a loaded machine)
                while server.sb.clients[cid].subs != want:
                    await trio.sleep(0.05)
            await trio.sleep(0.5)  # frames keep running: no further SUBSCRIBE for the same view
            assert len(subscribes) == n_before + 1
            assert (await page.evaluate("window.entitynet.stats()"))["subscribesSent"] == sent_before + 1
            old = set(map(int, cells_at(x, y, z)))
            assert set(subscribes[-1].added) == want - old and set(subscribes[-1].removed) == old - want

            # the canvas has drawn: city pixels, and entity colours somewhere
            await page.evaluate(f"window.entitynet.setCamera({x}, {y}, {z})")
            await trio.sleep(2.0)
            shot = await page.screenshot()
            (tmp_path / "viewer.png").write_bytes(shot)
            await page.evaluate("document.getElementById('panel').style.display = 'none'")
            await trio.sleep(0.3)
            img = _png(await page.screenshot())
            drawn = np.abs(img - BACKGROUND).sum(axis=2) > 12
            assert drawn.mean() > 0.2, f"only {drawn.mean():.1%} of the canvas drawn"
            r, g, b = img[:, :, 0], img[:, :, 1], img[:, :, 2]
            walkers = ((r > 150) & (b > 120) & (g * 2 < r) & (g * 2 < b)).sum()  # magenta, lit or in shade
            assert walkers > 0, "no pedestrian drawn"
            by_type = await page.evaluate("window.entitynet.byType()")
            print(f"first entity after {first_entity_s:.2f} s; page: {stats}; by type {by_type}; "
                  f"screenshot {tmp_path / 'viewer.png'}")
        nursery.cancel_scope.cancel()
