"""Headless Chromium driven over the DevTools protocol (CDP), for the viewer's browser test and measurements.

Why CDP directly and not playwright: a playwright release drives the Chromium it bundles, and Debian's
`chromium` moves with every security update (150 one week, 156 the next; no playwright release bundles 150), so
a pin is soon stale. The few commands needed here (open a page, evaluate, screenshot) have been stable in CDP
for years, and trio-websocket is already a dependency. The browser is Debian's (`apt-get install chromium`),
never downloaded; WebGL runs on SwiftShader (`--use-angle=swiftshader --enable-unsafe-swiftshader`).
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import shutil
import subprocess
import tempfile
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import trio
import trio_websocket

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class BrowserError(RuntimeError):
    """The browser could not be started, or a page command failed (the message says which)."""


def find_chromium() -> str | None:
    """$ENTITYNET_CHROMIUM, else the first Chromium on PATH, else None."""
    env = os.environ.get("ENTITYNET_CHROMIUM")
    if env:
        return env
    return next((p for p in map(shutil.which, CANDIDATES) if p), None)


class Page:
    """One headless tab: `goto`, `evaluate`, `wait_for`, `screenshot`. Made by `open_chromium`."""

    def __init__(self, ws: trio_websocket.WebSocketConnection) -> None:
        self.console: list[str] = []  # console messages and uncaught exceptions of the page
        self._ws = ws
        self._ids = itertools.count(1)
        self._waiting: dict[int, tuple[trio.Event, list]] = {}
        self._session: str | None = None

    async def _attach(self, width: int, height: int) -> None:
        target = await self.send("Target.createTarget", {"url": "about:blank"})
        attached = await self.send("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})
        self._session = attached["sessionId"]
        for method in ("Page.enable", "Runtime.enable"):
            await self.send(method)
        await self.send("Emulation.setDeviceMetricsOverride", {"width": width, "height": height,
                                                               "deviceScaleFactor": 1, "mobile": False})

    async def _reader(self) -> None:
        try:
            while True:
                msg = json.loads(await self._ws.get_message())
                if "id" in msg and msg["id"] in self._waiting:
                    event, box = self._waiting.pop(msg["id"])
                    box.append(msg)
                    event.set()
                elif msg.get("method") == "Runtime.consoleAPICalled":
                    p = msg["params"]
                    self.console.append(f"{p['type']}: " + " ".join(str(a.get("value", a.get("description", "")))
                                                                    for a in p.get("args", [])))
                elif msg.get("method") == "Runtime.exceptionThrown":
                    d = msg["params"]["exceptionDetails"]
                    self.console.append("exception: " + d.get("exception", {}).get("description", d.get("text", "")))
        except trio_websocket.ConnectionClosed:
            for event, _box in self._waiting.values():
                event.set()

    async def send(self, method: str, params: dict[str, Any] | None = None, timeout: float = 30.0) -> dict:
        """One CDP command (to the tab once attached); its result, or BrowserError."""
        mid = next(self._ids)
        msg: dict[str, Any] = {"id": mid, "method": method, "params": params or {}}
        if self._session is not None:
            msg["sessionId"] = self._session
        event, box = trio.Event(), []
        self._waiting[mid] = (event, box)
        await self._ws.send_message(json.dumps(msg))
        with trio.move_on_after(timeout):
            await event.wait()
        self._waiting.pop(mid, None)
        if not box:
            raise BrowserError(f"{method}: no answer within {timeout:g} s")
        if "error" in box[0]:
            raise BrowserError(f"{method}: {box[0]['error'].get('message')}")
        return box[0].get("result", {})

    async def goto(self, url: str) -> None:
        """Navigate and fail with the browser's own reason (a refused connection, a bad address)."""
        result = await self.send("Page.navigate", {"url": url})
        if result.get("errorText"):
            raise BrowserError(f"cannot open {url}: {result['errorText']}")

    async def evaluate(self, expression: str, timeout: float = 30.0) -> Any:
        """The value of a JavaScript expression in the page (promises awaited), as JSON."""
        result = await self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                      "awaitPromise": True}, timeout)
        if "exceptionDetails" in result:
            d = result["exceptionDetails"]
            raise BrowserError(f"{expression[:60]}: {d.get('exception', {}).get('description', d.get('text'))}")
        return result["result"].get("value")

    async def wait_for(self, expression: str, timeout: float = 30.0, every: float = 0.1) -> Any:
        """Poll until the expression is truthy; its value, or BrowserError after `timeout` seconds."""
        deadline = trio.current_time() + timeout
        while True:
            value = await self.evaluate(expression)
            if value:
                return value
            if trio.current_time() > deadline:
                raise BrowserError(f"timed out after {timeout:g} s waiting for {expression!r}; page console: "
                                   + " | ".join(self.console[-5:]))
            await trio.sleep(every)

    async def screenshot(self, timeout: float = 120.0) -> bytes:
        """The tab as PNG bytes (a page busy rendering on a software GPU may take a while)."""
        result = await self.send("Page.captureScreenshot", {"format": "png"}, timeout)
        return base64.b64decode(result["data"])


@asynccontextmanager
async def open_chromium(executable: str | None = None, width: int = 1280, height: int = 800,
                        start_timeout: float = 30.0) -> AsyncIterator[Page]:
    """`async with open_chromium() as page:` a headless Chromium with one tab, closed (and its profile
    removed) on exit. BrowserError when no Chromium is found or it does not start within `start_timeout`."""
    exe = executable or find_chromium()
    if exe is None:
        raise BrowserError("no Chromium found (apt-get install chromium, or set ENTITYNET_CHROMIUM)")
    profile = tempfile.mkdtemp(prefix="entitynet-chromium-")
    args = [exe, "--headless=new", "--remote-debugging-port=0", f"--user-data-dir={profile}", "--no-first-run",
            "--no-default-browser-check", "--disable-extensions", "--mute-audio", "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", f"--window-size={width},{height}",
            "about:blank"]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        args.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
    proc = await trio.lowlevel.open_process(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        url = await _devtools_url(proc, exe, Path(profile) / "DevToolsActivePort", start_timeout)
        async with trio.open_nursery() as nursery:
            ws = await trio_websocket.connect_websocket_url(nursery, url, max_message_size=64 << 20)
            page = Page(ws)
            nursery.start_soon(page._reader)
            await page._attach(width, height)
            try:
                yield page
            finally:
                nursery.cancel_scope.cancel()
    finally:
        with trio.CancelScope(shield=True):
            if proc.poll() is None:
                proc.terminate()
                with trio.move_on_after(5):
                    await proc.wait()
                if proc.poll() is None:
                    proc.kill()
                    await proc.wait()
            shutil.rmtree(profile, ignore_errors=True)


async def _devtools_url(proc: trio.Process, exe: str, port_file: Path, timeout: float) -> str:
    """The browser's DevTools WebSocket URL, from the file Chromium writes once it listens."""
    with trio.move_on_after(timeout):
        while True:
            if proc.poll() is not None:
                raise BrowserError(f"{exe} exited with status {proc.returncode} at start")
            if port_file.exists():
                lines = port_file.read_text().split()
                if len(lines) >= 2:
                    return f"ws://127.0.0.1:{int(lines[0])}{lines[1]}"
            await trio.sleep(0.05)
    raise BrowserError(f"{exe} did not open its DevTools port within {timeout:g} s")
