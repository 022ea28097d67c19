"""Failed logins are throttled by the peer's own address, over plain TCP, TLS and WebSocket alike."""

from __future__ import annotations

import shutil
import ssl
import subprocess

import pytest
import trio
import trio_websocket

from entitynet import protocol as P
from entitynet.server.peers import throttle_key
from tests.entitynet.server_helpers import DIGEST, running


def test_throttle_key():
    assert throttle_key("127.0.0.1") == "127.0.0.1"
    assert throttle_key("::ffff:10.1.2.3") == "10.1.2.3"
    assert throttle_key("2001:db8:1:2:aaaa::1") == throttle_key("2001:db8:1:2:bbbb::7") == "2001:db8:1:2::/64"
    assert throttle_key("fe80::1%eth0") == "fe80::/64"
    assert throttle_key(None) == "?" and throttle_key("") == "?"


def _peers(server) -> set[str]:
    return {c.peer for c in server.sb.clients.values()}


async def _wrong_hello_ws(port: int) -> list[P.Message]:
    async with trio_websocket.open_websocket_url(f"ws://127.0.0.1:{port}/") as ws:
        await ws.send_message(P.encode_payload([P.Hello(P.PROTOCOL_VERSION, "guess", DIGEST)]))
        return P.decode_payload(await ws.get_message())


async def test_websocket_logins_throttled_by_address(tmp_path):
    db = str(tmp_path / "u.sqlite")
    switch = {"auth_fail_free": 1, "auth_fail_base_s": 30.0}
    async with running(open_mode=False, users_db=db, ws_port=0, switch=switch) as server:
        codes = [(await _wrong_hello_ws(server.ws_port))[0].code for _ in range(3)]
        assert codes == [P.ErrorCode.AUTH_FAILED, P.ErrorCode.AUTH_FAILED, P.ErrorCode.AUTH_THROTTLED]
        assert "127.0.0.1" in server.sb.auth_throttle._peers


async def test_tls_clients_keyed_by_their_address(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl not available to make a test certificate")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    san = "subjectAltName=DNS:localhost,IP:127.0.0.1"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "1", "-subj", "/CN=localhost", "-addext", san],
                   check=True, capture_output=True)
    ctx = ssl.create_default_context(cafile=str(cert))
    async with running(tls_cert=str(cert), tls_key=str(key)) as server:
        stream = await trio.open_ssl_over_tcp_stream("127.0.0.1", server.port, ssl_context=ctx)
        await stream.send_all(P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "", DIGEST)]))
        dec = P.FrameDecoder()
        with trio.fail_after(5):
            while (msgs := dec.next_messages()) is None:
                dec.receive_data(await stream.receive_some(65536))
        assert isinstance(msgs[0], P.Welcome)
        assert _peers(server) == {"127.0.0.1"}  # not "tls" for every TLS client
        await stream.aclose()
