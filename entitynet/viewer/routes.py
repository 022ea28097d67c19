"""The HTTP routes of the browser viewer (`entitynet serve --http-port P`), added to the server's h11 router.

    /                      the page (static/index.html)
    /static/...            the page's files; /static/dist/viewer.js is the bundle `npm run build` makes
    /viewer/config.json    how to reach the switchboard: WebSocket port, TLS, digest, token policy
    /viewer/geometry.json  the artifact's geometry (entitynet/viewer/geometry.py), gzip when accepted
    /viewer/pvs/N.json     the visibility cells of view cell N
    /metrics               as on --metrics-port

Everything is prepared once at start (the geometry JSON and its gzip), so a request costs a dict lookup; the
static files are the ones present at start (a whitelist: no path from a request ever reaches the file system).
A page whose bundle was not built answers 503 with the command that builds it, instead of a blank page.
"""

from __future__ import annotations

import gzip
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h11

from entitynet.server.http import HttpLimits, HttpServer, Response, Router, text
from entitynet.viewer.geometry import export_geometry, pvs_cells

STATIC = Path(__file__).parent / "static"
BUNDLE = "dist/viewer.js"
BUILD_HINT = "the viewer's bundle is missing: run `npm ci && npm run build` in the project root"
_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
          ".css": "text/css; charset=utf-8", ".json": "application/json", ".map": "application/json",
          ".png": "image/png", ".svg": "image/svg+xml"}
_NO_STORE = ("Cache-Control", "no-store")


def _json(body: Any) -> bytes:
    return json.dumps(body, separators=(",", ":")).encode()


def _accepts_gzip(request: h11.Request) -> bool:
    return any(k == b"accept-encoding" and b"gzip" in v for k, v in request.headers)


class ViewerSite:
    """The viewer's routes for one server: `add_to(router)`; `ws_port` is read when the page asks."""

    def __init__(self, topo: Any, *, ws_port: Callable[[], int | None], tls: bool, open_mode: bool,
                 static_dir: Path = STATIC) -> None:
        self.topo = topo
        self._ws_port = ws_port
        self.tls = tls
        self.open_mode = open_mode
        self.static_dir = static_dir
        geometry = _json(export_geometry(topo))
        self._geometry = geometry
        self._geometry_gz = gzip.compress(geometry, 6, mtime=0)
        self._files = {p.relative_to(static_dir).as_posix(): p for p in static_dir.rglob("*") if p.is_file()}
        self._pvs = None
        if "pvs" in topo.meta:
            from topology.pvs_index import PvsIndex

            self._pvs = PvsIndex.from_topology(topo)
        self._n_view_cells = self._pvs.grid.n_view_cells if self._pvs is not None else 0

    def add_to(self, router: Router) -> None:
        """Mount the page, its config, geometry, per-view-cell PVS and static files on the server's router."""
        router.add("/", self.index)
        router.add("/index.html", self.index)
        router.add("/viewer/config.json", self.config)
        router.add("/viewer/geometry.json", self.geometry)
        router.add_prefix("/viewer/pvs/", self.pvs)
        router.add_prefix("/static/", self.static)

    def config_dict(self) -> dict[str, Any]:
        """What the page needs to join as a viewer: the WebSocket port (read now: it is known only once the
        listener is open), TLS, the digest its HELLO must carry, and whether a token is needed."""
        return {"ws_port": self._ws_port(), "tls": self.tls, "digest": self.topo.digest,
                "auth": "open" if self.open_mode else "token", "protocol_version": 1}

    def config(self, request: h11.Request) -> Response:
        """GET /viewer/config.json: 503 with the reason when the server has no WebSocket port to join."""
        if self._ws_port() is None:
            return text(503, "this server has no WebSocket port (start it with --ws-port)")
        return Response(200, _json(self.config_dict()), "application/json", [_NO_STORE])

    def geometry(self, request: h11.Request) -> Response:
        """GET /viewer/geometry.json: the city, encoded once at start, gzipped when the browser accepts it
        (0.87 MB becomes 0.32 MB)."""
        if _accepts_gzip(request):
            return Response(200, self._geometry_gz, "application/json", [("Content-Encoding", "gzip")])
        return Response(200, self._geometry, "application/json")

    def pvs(self, request: h11.Request) -> Response:
        """GET /viewer/pvs/N.json: one view cell's visible cells, fetched as the camera enters it, so the page
        never downloads the whole PVS."""
        name = request.target.split(b"?", 1)[0].decode("ascii", "replace").rsplit("/", 1)[-1]
        if self._pvs is None:
            return text(404, "the artifact has no PVS")
        stem = name.removesuffix(".json")
        if not stem.isdigit() or int(stem) >= self._n_view_cells:
            return text(404, "no such view cell")
        return Response(200, _json(pvs_cells(self.topo, self._pvs, int(stem))), "application/json")

    def index(self, request: h11.Request) -> Response:
        """GET /: the page, or 503 saying how to build the bundle when `npm run build` has not run."""
        if BUNDLE not in self._files:
            return text(503, BUILD_HINT)
        return self._file("index.html")

    def static(self, request: h11.Request) -> Response:
        """GET /static/...: only files listed at start are served, so no request path reaches the file system."""
        path = request.target.split(b"?", 1)[0].decode("ascii", "replace").removeprefix("/static/")
        if path == BUNDLE and BUNDLE not in self._files:
            return text(503, BUILD_HINT)
        return self._file(path)

    def _file(self, rel: str) -> Response:
        p = self._files.get(rel)
        if p is None:
            return text(404, "not found")
        ctype = _TYPES.get(p.suffix, "application/octet-stream")
        return Response(200, p.read_bytes(), ctype, [_NO_STORE])


def viewer_http(server: Any) -> HttpServer:
    """The HTTP server of `--http-port` for a `entitynet.server.app.Server`: the viewer's routes and /metrics.

    Refuses (ConfigError) a configuration the page could not work with: no artifact to draw, or no WebSocket
    port to reach the switchboard through."""
    from entitynet.server.config import ConfigError
    from entitynet.server.metrics import metrics_handler

    cfg = server.config
    if not cfg.topology:
        raise ConfigError("--http-port (the viewer) needs a topology artifact")
    if cfg.ws_port is None:
        raise ConfigError("--http-port (the viewer) needs --ws-port: the page reaches the switchboard over WebSocket")
    from topology import artifact

    try:
        topo = artifact.load(cfg.topology)
    except (OSError, artifact.ArtifactError) as exc:
        raise ConfigError(f"cannot load topology {cfg.topology}: {exc}") from exc
    site = ViewerSite(topo, ws_port=lambda: server.ws_port, tls=server.ssl is not None, open_mode=cfg.open_mode)
    router = Router()
    router.add("/metrics", metrics_handler(server.metrics.registry))
    site.add_to(router)
    limits = HttpLimits(header_timeout=cfg.http_header_timeout, idle_timeout=cfg.http_idle_timeout,
                        max_connections=cfg.http_max_connections, max_request_bytes=cfg.http_max_request)
    return HttpServer(router, limits, server.admission, name="viewer")
