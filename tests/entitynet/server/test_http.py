"""The metrics HTTP server on trio (entitynet/server/http.py) over real loopback sockets."""

from __future__ import annotations

import threading

import trio

from tests.entitynet.server_helpers import running


async def _request(port: int, raw: bytes, timeout: float = 5.0, body: bool = True) -> bytes:
    """Send `raw`, read until the server closes or a complete response (by Content-Length) arrived."""
    stream = await trio.open_tcp_stream("127.0.0.1", port)
    got = b""
    with trio.fail_after(timeout):
        await stream.send_all(raw)
        while True:
            data = await stream.receive_some(65_536)
            got += data
            head, sep, rest = got.partition(b"\r\n\r\n")
            if not data:
                break
            if sep and not body:
                break
            if sep:
                lengths = [int(line.split(b":")[1]) for line in head.split(b"\r\n")
                           if line.lower().startswith(b"content-length:")]
                if lengths and len(rest) >= lengths[0]:
                    break
    await stream.aclose()
    return got


async def _closed_within(stream: trio.SocketStream, seconds: float) -> bool:
    """True when the server closes `stream` within `seconds` (reading and dropping what it sends)."""
    with trio.move_on_after(seconds):
        while True:
            try:
                data = await stream.receive_some(4096)
            except trio.BrokenResourceError:
                return True
            if not data:
                return True
    return False


async def test_metrics_text_404_and_methods():
    async with running(metrics_port=0) as server:
        port = server.metrics_port
        got = await _request(port, b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")
        assert got.startswith(b"HTTP/1.1 200 ")
        assert b"Content-Type: text/plain; version=" in got.split(b"\r\n\r\n")[0]
        assert b"# TYPE entitynet_connections gauge" in got and b"entitynet_connections 0.0" in got
        head = await _request(port, b"HEAD /metrics HTTP/1.1\r\nHost: x\r\n\r\n", body=False)
        assert head.startswith(b"HTTP/1.1 200 ") and head.endswith(b"\r\n\r\n")  # no body
        assert (await _request(port, b"GET /viewer/ HTTP/1.1\r\nHost: x\r\n\r\n")).startswith(b"HTTP/1.1 404 ")
        assert (await _request(port, b"POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n\r\n")
                ).startswith(b"HTTP/1.1 405 ")
        assert (await _request(port, b"BLAH\r\n\r\n")).startswith(b"HTTP/1.1 400 ")


async def test_request_size_is_bounded():
    async with running(metrics_port=0, http_max_request=2048) as server:
        big = b"GET /metrics HTTP/1.1\r\nHost: x\r\nX-Pad: " + b"a" * 4096 + b"\r\n\r\n"
        assert (await _request(server.metrics_port, big)).startswith(b"HTTP/1.1 431 ")
        body = b"GET /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 5000\r\n\r\n" + b"b" * 5000
        assert (await _request(server.metrics_port, body)).startswith(b"HTTP/1.1 413 ")


async def test_idle_and_slow_connections_are_closed():
    async with running(metrics_port=0, http_header_timeout=0.3, http_idle_timeout=0.5) as server:
        port = server.metrics_port
        silent = await trio.open_tcp_stream("127.0.0.1", port)  # never sends a byte
        assert await _closed_within(silent, 3.0)
        slow = await trio.open_tcp_stream("127.0.0.1", port)  # starts a request, never finishes it
        await slow.send_all(b"GET /metrics HTTP/1.1\r\n")
        assert await _closed_within(slow, 3.0)
        kept = await trio.open_tcp_stream("127.0.0.1", port)  # one request, then keep-alive idle
        await kept.send_all(b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")
        assert await _closed_within(kept, 3.0)


async def test_connection_flood_is_bounded_and_makes_no_threads():
    n_open, limit = 60, 20
    async with running(metrics_port=0, http_max_connections=limit, http_header_timeout=2.0) as server:
        threads = threading.active_count()
        streams = []
        for _ in range(n_open):
            streams.append(await trio.open_tcp_stream("127.0.0.1", server.metrics_port))
        with trio.fail_after(5):
            while server.http.open < limit:
                await trio.sleep(0.01)
        refused = 0
        with trio.fail_after(5):
            for s in streams[limit:]:
                data = await s.receive_some(4096)
                refused += data.startswith(b"HTTP/1.1 503 ")
        assert refused == n_open - limit
        assert server.http.open == limit
        assert threading.active_count() <= threads  # one task per connection, no thread
        for s in streams:
            await s.aclose()
        got = await _request(server.metrics_port, b"GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n")
        assert got.startswith(b"HTTP/1.1 200 ")
