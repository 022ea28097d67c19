"""Measure the browser viewer in headless Chromium (SwiftShader WebGL): frame time with N live entities and the
time from opening the page to the first entity. `python -m sims.viewer_bench --entities 500 2000 --out F.json`.

Runs the demo in this process (bundled Helsinki with PVS, the bundled schedule's trams and buses on top of the
pedestrians and cars, no Python viewers), opens
the page at its default camera (above the roofs), waits `--settle` seconds, then samples the page's
requestAnimationFrame intervals for `--seconds`. Figures depend on the machine: SwiftShader renders on the CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import trio

from sims.browser import open_chromium
from sims.demo import DemoConfig, run_demo


async def measure(topo, path, entities: int, settle: float, seconds: float, screenshot: str | None,
                  schedule=None) -> dict:
    """One live demo of `entities` and the page in headless Chromium: time to the first entity, then frame times
    over `seconds` once `settle` has passed (the page's own requestAnimationFrame clock)."""
    config = DemoConfig(entities=entities, viewers=0, connections=4, duration=settle + seconds + 120,
                        summary_every=1e9, http_port=0)
    async with trio.open_nursery() as nursery:
        server = await nursery.start(run_demo, topo, path, config, lambda m: None, schedule)
        async with open_chromium(width=1280, height=800) as page:
            opened = time.perf_counter()
            await page.goto(f"http://127.0.0.1:{server.http_port}/")
            await page.wait_for("window.entitynet && window.entitynet.stats && window.entitynet.stats().held > 0",
                                timeout=300, every=0.05)
            first = time.perf_counter() - opened
            await trio.sleep(settle)
            before = await page.evaluate("window.entitynet.stats().frame")
            await trio.sleep(seconds)
            frames = await page.evaluate("window.entitynet.frameTimes()")
            stats = await page.evaluate("window.entitynet.stats()")
            n = stats["frame"] - before
            frames = frames[-n:] if n > 0 else frames
            if screenshot:
                with open(screenshot, "wb") as f:
                    f.write(await page.screenshot())
        nursery.cancel_scope.cancel()
    ordered = sorted(frames)
    return {"entities": entities, "first_entity_s": round(first, 2),
            "first_entity_page_ms": stats["firstEntityMs"], "held": stats["held"], "drawn": stats["visible"],
            "frames": len(frames), "frame_ms_median": round(statistics.median(frames), 1) if frames else None,
            "frame_ms_p95": round(ordered[int(0.95 * (len(ordered) - 1))], 1) if frames else None,
            "fps": round(1000.0 / statistics.mean(frames), 2) if frames else None}


async def measure_library(topo, path, lib: str, n: int, settle: float, seconds: float) -> dict:
    """bench.html: the same city and n synthetic entities drawn by `lib` (deck or three); no server entities."""
    config = DemoConfig(entities=1, viewers=0, connections=1, duration=settle + seconds + 300, summary_every=1e9,
                        http_port=0)
    async with trio.open_nursery() as nursery:
        server = await nursery.start(run_demo, topo, path, config, lambda m: None)
        async with open_chromium(width=1280, height=800) as page:
            await page.goto(f"http://127.0.0.1:{server.http_port}/static/bench.html#lib={lib}&n={n}")
            await page.wait_for("window.bench && (window.bench.frames.length > 1 || window.bench.error)", timeout=300)
            error = await page.evaluate("window.bench.error || null")
            if error:
                raise RuntimeError(f"{lib}: {error}")
            await trio.sleep(settle)
            before = await page.evaluate("window.bench.frames.length")
            await trio.sleep(seconds)
            frames = (await page.evaluate("window.bench.frames"))[before:]
        nursery.cancel_scope.cancel()
    return {"library": lib, "entities": n, "frames": len(frames),
            "frame_ms_median": round(statistics.median(frames), 1), "fps": round(1000.0 / statistics.mean(frames), 2)}


def main() -> None:
    """`python -m sims.viewer_bench`: the viewer's frame time at each entity count (and, with --libraries, per
    WebGL library), printed as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--entities", type=int, nargs="+", default=[500, 2000])
    ap.add_argument("--settle", type=float, default=10.0)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--screenshot", help="save the last run's screenshot here (PNG)")
    ap.add_argument("--out", help="write the results as JSON here")
    ap.add_argument("--libraries", nargs="*", metavar="LIB",
                    help="instead: the library benchmark (bench.html) for these libraries (deck three)")
    args = ap.parse_args()
    from entitynet.topology_cache import bundled_topology, cache_dir
    from sims.engine.schedule import BUNDLED_FEED, load_schedule

    topo, path = bundled_topology(print, with_pvs=True)
    schedule = load_schedule(BUNDLED_FEED, topo, cache=cache_dir())
    results = []
    for lib in args.libraries or ():
        for n in args.entities:
            r = trio.run(measure_library, topo, path, lib, n, args.settle, args.seconds)
            print(json.dumps(r), flush=True)
            results.append(r)
    for k, n in enumerate(args.entities if not args.libraries else ()):
        r = trio.run(measure, topo, path, n, args.settle, args.seconds, args.screenshot if k == 0 else None,
                     schedule)
        print(json.dumps(r), flush=True)
        results.append(r)
    report = {"suite": "viewer", "machine": {"cores": os.cpu_count(), "python": platform.python_version(),
                                             "load_avg": os.getloadavg(), "renderer": "SwiftShader (CPU)"},
              "params": vars(args), "results": results}
    if args.out:
        with open(args.out, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
