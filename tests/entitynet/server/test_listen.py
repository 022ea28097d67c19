"""The connection gate (entitynet/server/listen.py): client slots, bounded TLS handshakes and WebSocket upgrades."""

from __future__ import annotations

import logging
import ssl

import pytest
import trio
import trio_websocket

from entitynet import protocol as P
from tests.entitynet.server.tls_helpers import make_cert
from tests.entitynet.server_helpers import DIGEST, Raw, running


def _no_tracebacks(caplog) -> None:
    assert [r.getMessage() for r in caplog.records if r.exc_info] == []


async def _wait_until(pred, timeout: float = 3.0) -> None:
    with trio.fail_after(timeout):
        while not pred():
            await trio.sleep(0.01)


async def _closed_by_server(stream, timeout: float) -> bool:
    with trio.move_on_after(timeout):
        while True:
            try:
                if not await stream.receive_some(4096):
                    return True
            except trio.BrokenResourceError:
                return True
    return False


async def test_pending_upgrades_hold_client_slots_and_time_out(caplog):
    caplog.set_level(logging.INFO, logger="entitynet.server")
    async with running(ws_port=0, max_clients=3, handshake_timeout=0.5) as server:
        pending = [await trio.open_tcp_stream("127.0.0.1", server.ws_port) for _ in range(3)]
        await pending[0].send_all(b"GET / HTTP/1.1\r\nHost: x\r\n")  # half an upgrade request
        await _wait_until(lambda: server.admission.clients == 3)
        c = await Raw.connect(server, hello=False)  # a TCP client: the upgrades in progress fill the server
        assert [m.code for m in await c.expect_closed()] == [P.ErrorCode.SERVER_FULL]
        for s in pending:  # closed after the handshake timeout, not trio-websocket's 60 s
            assert await _closed_by_server(s, 3.0)
        await _wait_until(lambda: server.admission.clients == 0)
        c = await Raw.connect(server)  # slots free again: HELLO is answered with WELCOME
        await c.aclose()
    assert "WebSocket upgrade timed out" in caplog.text
    _no_tracebacks(caplog)


async def test_upgrades_closed_by_the_client_are_freed_at_once(caplog):
    caplog.set_level(logging.INFO, logger="entitynet.server")
    async with running(ws_port=0, max_clients=2, handshake_timeout=30.0) as server:
        for _ in range(5):  # far more sockets than slots, each closed before upgrading
            pair = [await trio.open_tcp_stream("127.0.0.1", server.ws_port) for _ in range(2)]
            await _wait_until(lambda: server.admission.clients == 2)
            for s in pair:
                await s.aclose()
            await _wait_until(lambda: server.admission.clients == 0, timeout=2.0)  # << the 30 s timeout
        async with trio_websocket.open_websocket_url(f"ws://127.0.0.1:{server.ws_port}/") as ws:
            await ws.send_message(P.encode_payload([P.Hello(1, "", DIGEST)]))
            with trio.fail_after(5):
                assert isinstance(P.decode_payload(await ws.get_message())[0], P.Welcome)
    _no_tracebacks(caplog)


async def test_websocket_refused_when_full_and_bad_requests_answered():
    async with running(ws_port=0, max_clients=1) as server:
        c = await Raw.connect(server)
        with pytest.raises(trio_websocket.ConnectionRejected) as info:
            async with trio_websocket.open_websocket_url(f"ws://127.0.0.1:{server.ws_port}/"):
                pass
        assert info.value.status_code == 503
        await c.aclose()
        await _wait_until(lambda: server.admission.clients == 0)
        s = await trio.open_tcp_stream("127.0.0.1", server.ws_port)
        await s.send_all(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")  # no Upgrade header
        with trio.fail_after(3):
            assert (await s.receive_some(4096)).startswith(b"HTTP/1.1 400 ")


async def test_tls_peer_address_is_logged(tmp_path, caplog):
    caplog.set_level(logging.DEBUG, logger="entitynet.server")
    cert, key = make_cert(tmp_path)
    ctx = ssl.create_default_context(cafile=cert)
    async with running(tls_cert=cert, tls_key=key) as server:
        stream = await trio.open_ssl_over_tcp_stream("localhost", server.port, ssl_context=ctx)
        c = Raw(stream)
        await c.send(P.Hello(P.PROTOCOL_VERSION, "", DIGEST))
        await c.expect(P.Welcome)
        local_port = stream.transport_stream.socket.getsockname()[1]
        await c.aclose()
    connects = [r.getMessage() for r in caplog.records if r.getMessage().startswith("connect ")]
    assert any(f"peer=127.0.0.1:{local_port}" in m for m in connects), connects


async def test_stalled_tls_handshake_is_logged_as_such(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="entitynet.server")
    cert, key = make_cert(tmp_path)
    async with running(tls_cert=cert, tls_key=key, handshake_timeout=0.3, stall_timeout=0.3) as server:
        silent = await trio.open_tcp_stream("127.0.0.1", server.port)  # TCP only: no ClientHello
        local_port = silent.socket.getsockname()[1]
        assert await _closed_by_server(silent, 3.0)
        garbage = await trio.open_tcp_stream("127.0.0.1", server.port)
        await garbage.send_all(b"GET / HTTP/1.1\r\n\r\n")  # not TLS at all
        assert await _closed_by_server(garbage, 3.0)
        await _wait_until(lambda: server.admission.clients == 0)
    text = caplog.text
    assert f"TLS handshake timed out peer=127.0.0.1:{local_port}" in text
    assert "TLS handshake failed" in text
    assert "slow consumer" not in text
    _no_tracebacks(caplog)
