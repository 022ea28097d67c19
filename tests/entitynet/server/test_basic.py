"""The trio server over real loopback sockets: TCP, WebSocket, handshake, metrics, shutdown, topology."""

from __future__ import annotations

import urllib.request

import pytest
import trio
import trio_websocket

from entitynet import protocol as P
from entitynet.server import ConfigError, Server, ServerConfig, serve
from tests.entitynet.server_helpers import DIGEST, Raw, flows, pair, running


async def test_publish_reaches_tcp_and_websocket_viewers():
    async with running(ws_port=0) as server:
        pub, view = await pair(server, cell=3)
        async with trio_websocket.open_websocket_url(f"ws://127.0.0.1:{server.ws_port}/") as ws:
            await ws.send_message(P.encode_payload([P.Hello(1, "", DIGEST), P.Subscribe((3,), ()), P.Ping(7)]))
            got = []
            with trio.fail_after(5):
                while not any(isinstance(m, P.Pong) for m in got):
                    got += P.decode_payload(await ws.get_message())
            assert isinstance(got[0], P.Welcome)
            await pub.send(P.Publish(5, 1, (3, 4), 1000, b"hello"))
            u = await view.expect(P.Update)
            assert (u.cells, u.payload, u.validity_ms) == ((3, 4), b"hello", 1000)
            with trio.fail_after(5):
                while True:
                    ms = [m for m in P.decode_payload(await ws.get_message()) if isinstance(m, P.Update)]
                    if ms:
                        break
            assert ms[0] == u
            await pub.aclose()  # the publisher leaves: its entity leaves with it
            assert (await view.expect(P.Leave)).entity == u.entity


async def test_topology_mismatch_and_auth_refused_clearly(tmp_path):
    from entitynet.auth import TokenStore

    db = tmp_path / "users.sqlite"
    token = TokenStore(db).add_user("alice")
    async with running(open_mode=False, users_db=str(db)) as server:
        c = await Raw.connect(server, hello=False)
        await c.send(P.Hello(1, token, "some-other-digest"))
        (err,) = await c.expect_closed()
        assert err.code == P.ErrorCode.TOPOLOGY_MISMATCH and "digest" in err.text
        c = await Raw.connect(server, hello=False)
        await c.send(P.Hello(1, "wrong", DIGEST))
        assert [m.code for m in await c.expect_closed()] == [P.ErrorCode.AUTH_FAILED]
        c = await Raw.connect(server, hello=False)
        await c.send(P.Hello(1, token, DIGEST))
        assert isinstance(await c.expect(P.Welcome), P.Welcome)
        assert server.sb.clients[max(server.sb.clients)].user_id == "alice"


async def test_metrics_endpoint():
    async with running(metrics_port=0) as server:
        pub, view = await pair(server)
        await flows(pub, view, 1)
        body = await trio.to_thread.run_sync(
            lambda: urllib.request.urlopen(f"http://127.0.0.1:{server.metrics_port}/metrics").read().decode()
        )
        assert "entitynet_connections 2.0" in body
        assert "entitynet_updates_in_total 1.0" in body
        assert "entitynet_queue_latency_seconds_count" in body


async def test_graceful_shutdown_tells_clients():
    async with trio.open_nursery() as n:
        server: Server = await n.start(serve, ServerConfig(port=0, digest=DIGEST, n_cells=10, open_mode=True))
        c = await Raw.connect(server)
        n.start_soon(server.stop)
        got = await c.expect_closed()
        assert [m.code for m in got if isinstance(m, P.Error)] == [P.ErrorCode.SHUTTING_DOWN]


async def test_topology_artifact_gives_digest_and_cells(helsinki_path, helsinki):
    async with running(topology=str(helsinki_path), digest=None, n_cells=None) as server:
        assert server.sb.config.n_cells == helsinki.n_cells and server.sb.config.digest == helsinki.digest
        c = await Raw.connect(server, digest=helsinki.digest)
        await c.send(P.Subscribe((helsinki.n_cells,), ()))
        assert (await c.expect(P.Error)).code == P.ErrorCode.NO_SUCH_CELL


def test_config_errors(tmp_path):
    with pytest.raises(ConfigError):
        Server(ServerConfig(port=0, open_mode=True))
    with pytest.raises(ConfigError):
        Server(ServerConfig(port=0, topology=str(tmp_path / "missing.enttopo"), open_mode=True))
    with pytest.raises(ConfigError):
        Server(ServerConfig(port=0, digest="d", n_cells=1, open_mode=True, tls_cert="x.pem"))


def test_serve_command_reports_bad_topology_cleanly(tmp_path):
    from entitynet.cli import main

    assert main(["serve", "--topology", str(tmp_path / "missing.enttopo"), "--open"]) == 2


async def test_tls_listener(tmp_path):
    import shutil
    import ssl
    import subprocess

    if shutil.which("openssl") is None:
        pytest.skip("openssl not available to make a test certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "1", "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost"],
                   check=True, capture_output=True)
    from entitynet.connection import Connection

    ctx = ssl.create_default_context(cafile=str(cert))
    async with running(tls_cert=str(cert), tls_key=str(key)) as server, trio.open_nursery() as n:
        seen = []
        view = Connection(("localhost", server.port), DIGEST, ssl_context=ctx,
                          on_message=lambda m: isinstance(m, P.Update) and seen.append(m))
        await view.subscribe((1,))
        await n.start(view.run)
        pub = Connection(("localhost", server.port), DIGEST, ssl_context=ctx)
        await n.start(pub.run)
        await pub.publish(P.Publish(1, 1, (1,), 1000, b"tls"))
        with trio.fail_after(5):
            while not seen:
                await trio.sleep(0.01)
        assert seen[0].payload == b"tls"
        n.cancel_scope.cancel()
