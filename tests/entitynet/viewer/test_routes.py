"""`entitynet serve --http-port`: the viewer's routes over real HTTP on loopback, and /metrics beside them."""

from __future__ import annotations

import gzip
import json

import pytest
import trio

from entitynet.server.app import Server, serve
from entitynet.server.config import ConfigError, ServerConfig
from entitynet.viewer.geometry import FORMAT


async def _get(port: int, path: str, headers: str = "") -> tuple[int, dict[str, str], bytes]:
    stream = await trio.open_tcp_stream("127.0.0.1", port)
    async with stream:
        await stream.send_all(f"GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n{headers}\r\n".encode())
        data = b""
        with trio.fail_after(10):
            while chunk := await stream.receive_some(1 << 20):
                data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode().split("\r\n")
    hdrs = {k.lower(): v.strip() for k, v in (line.split(":", 1) for line in lines[1:])}
    return int(lines[0].split()[1]), hdrs, body


async def test_viewer_routes(helsinki, helsinki_path):
    config = ServerConfig(port=0, ws_port=0, http_port=0, topology=str(helsinki_path), open_mode=True)
    async with trio.open_nursery() as nursery:
        server: Server = await nursery.start(serve, config)
        port = server.http_port
        status, hdrs, body = await _get(port, "/viewer/config.json")
        assert status == 200
        cfg = json.loads(body)
        assert cfg == {"ws_port": server.ws_port, "tls": False, "digest": helsinki.digest, "auth": "open",
                       "protocol_version": 1}
        status, hdrs, body = await _get(port, "/viewer/geometry.json", "Accept-Encoding: gzip\r\n")
        assert status == 200 and hdrs["content-encoding"] == "gzip"
        geo = json.loads(gzip.decompress(body))
        assert geo["format"] == FORMAT and geo["digest"] == helsinki.digest
        assert len(geo["buildings"]["polygons"]) == len(geo["buildings"]["height"]) == len(helsinki.building_height)
        assert len(geo["cells"]["polygons"]) == helsinki.n_cells and geo["net"]["n_edges"] == helsinki.n_edges
        assert geo["pvs"] is None  # this artifact was built without PVS: the page subscribes by distance
        status, _, plain = await _get(port, "/viewer/geometry.json")
        assert status == 200 and json.loads(plain) == geo
        assert (await _get(port, "/viewer/pvs/0.json"))[0] == 404  # no PVS here
        for bad in ("/static/../routes.py", "/static/%2e%2e/routes.py", "/static/js/nothing.js", "/nope"):
            assert (await _get(port, bad))[0] == 404, bad
        status, hdrs, body = await _get(port, "/static/js/motion.js")
        assert status == 200 and hdrs["content-type"].startswith("text/javascript") and b"class NetworkModel" in body
        status, _, body = await _get(port, "/metrics")
        assert status == 200 and b"entitynet_" in body
        nursery.cancel_scope.cancel()


def test_viewer_needs_a_websocket_port(helsinki_path):
    with pytest.raises(ConfigError, match="--ws-port"):
        Server(ServerConfig(port=0, http_port=0, topology=str(helsinki_path), open_mode=True))
