"""Entities stay legible in the 3D viewer: at the page's default camera (above the city, looking down on it)
every entity that is not hidden behind a building covers at least a few pixels of the canvas.

The page renders one instant twice, with and without the entities (`window.entitynet.entityFrames()`); the
pixels that differ are the entities'. Each such pixel is given to the nearest entity's projected middle, and
the entities that got any (those in view and not occluded) must each cover at least MIN_PIXELS. Real headless
Chromium (software WebGL) against a live demo on loopback; skips like test_browser.py without Chromium or the
built bundle.
"""

from __future__ import annotations

import base64
import io

import numpy as np
import pytest
import trio

from entitynet.viewer.routes import BUNDLE, STATIC
from sims.browser import find_chromium, open_chromium
from sims.demo import DemoConfig, run_demo
from tests.sims.test_demo import _one_tram

pytestmark = [
    pytest.mark.skipif(find_chromium() is None, reason="no Chromium installed (apt-get install chromium)"),
    pytest.mark.skipif(not (STATIC / BUNDLE).exists(), reason="viewer bundle not built (npm ci && npm run build)"),
]

WIDTH, HEIGHT = 1280, 800
MIN_PIXELS = 20  # an 8 px wide marker seen from above covers about 8 x 8; main's pedestrians covered 11-16
NEAR_PX = 25  # a differing pixel farther than this from every entity's middle belongs to none


def _rgb(data_url: str) -> np.ndarray:
    import matplotlib.image as mpimg

    png = base64.b64decode(data_url.split(",", 1)[1])
    return (mpimg.imread(io.BytesIO(png), format="png")[:, :, :3] * 255).round().astype(int)


def coverage(with_entities: np.ndarray, without: np.ndarray, middles: np.ndarray) -> np.ndarray:
    """Pixels each entity covers: the pixels that differ between the two renders, each given to the nearest
    middle (x, y in pixels) within NEAR_PX."""
    ys, xs = np.nonzero(np.abs(with_entities - without).sum(axis=2) > 0)
    counts = np.zeros(len(middles), dtype=int)
    if len(xs) == 0 or len(middles) == 0:
        return counts
    d = np.hypot(xs[:, None] - middles[None, :, 0], ys[:, None] - middles[None, :, 1])
    nearest = d.argmin(axis=1)
    near = d[np.arange(len(xs)), nearest] <= NEAR_PX
    np.add.at(counts, nearest[near], 1)
    return counts


def test_coverage_gives_pixels_to_the_nearest_middle():
    a = np.zeros((20, 70, 3), dtype=int)
    b = a.copy()
    b[2:5, 2:5] = 255  # 9 pixels by the first middle
    b[10, 30] = 7  # 1 pixel by the second
    b[19, 69] = 1  # too far from both: nobody's
    got = coverage(b, a, np.array([[3.0, 3.0], [30.0, 8.0]]))
    assert got.tolist() == [9, 1]
    assert coverage(a, a, np.array([[3.0, 3.0]])).tolist() == [0]
    assert coverage(b, a, np.zeros((0, 2))).tolist() == []


async def test_entities_cover_pixels_at_the_default_camera(helsinki, helsinki_path, tmp_path):
    config = DemoConfig(entities=120, viewers=0, connections=2, duration=60.0, summary_every=1000.0, seed=5,
                        http_port=0)
    async with trio.open_nursery() as nursery:
        server = await nursery.start(run_demo, helsinki, helsinki_path, config, lambda m: None, _one_tram(helsinki))
        async with open_chromium(width=WIDTH, height=HEIGHT) as page:
            await page.goto(f"http://127.0.0.1:{server.http_port}/")
            await page.wait_for("window.entitynet && window.entitynet.stats && window.entitynet.stats().held > 20",
                                timeout=90)
            await page.evaluate("document.getElementById('panel').style.display = 'none'")
            frames = await page.evaluate("window.entitynet.entityFrames()", timeout=120)
        nursery.cancel_scope.cancel()
    with_entities, without = _rgb(frames["withEntities"]), _rgb(frames["without"])
    assert with_entities.shape == (HEIGHT, WIDTH, 3)
    (tmp_path / "entities.png").write_bytes(base64.b64decode(frames["withEntities"].split(",", 1)[1]))
    on_screen = [e for e in frames["entities"]
                 if e["screen"] is not None and 0 <= e["screen"][0] < WIDTH and 0 <= e["screen"][1] < HEIGHT]
    assert len(on_screen) >= 20, f"only {len(on_screen)} entities in view at the default camera"
    counts = coverage(with_entities, without, np.array([e["screen"] for e in on_screen], dtype=float))
    seen = counts[counts > 0]  # the others are behind buildings
    assert len(seen) >= len(on_screen) // 3, f"{len(seen)} of {len(on_screen)} entities drawn at all"
    by_type: dict[int, list[int]] = {}
    for e, n in zip(on_screen, counts, strict=True):
        if n > 0:
            by_type.setdefault(e["etype"], []).append(int(n))
    print({t: (len(v), int(np.min(v)), int(np.median(v))) for t, v in by_type.items()}, tmp_path / "entities.png")
    small = [(e["etype"], int(n)) for e, n in zip(on_screen, counts, strict=True) if 0 < n < MIN_PIXELS]
    # an entity partly hidden behind a building's edge may show fewer pixels: allow a few such
    assert len(small) <= max(2, len(seen) // 10), f"{len(small)} of {len(seen)} drawn entities cover < " \
        f"{MIN_PIXELS} px: {small[:20]}"
    assert np.median(seen) >= 2 * MIN_PIXELS, f"median entity covers {np.median(seen)} px"
