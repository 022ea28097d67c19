"""The WebSocket upgrade, bounded: read the HTTP request ourselves, then hand the socket to trio-websocket.

Why: trio-websocket's server waits `connect_timeout` (60 s by default) for the upgrade request, and keeps
waiting even after the client has gone, outside any client count. A flood of sockets that never upgrade then
holds descriptors for a minute. Here the shell reads the request head itself, within the handshake timeout and
a size bound, notices at once when the client closes, and only a complete `GET ... Upgrade: websocket` head is
passed on: through a `HandoffListener` (a listener fed by a memory channel) to an ordinary
`trio_websocket.WebSocketServer`, with the bytes already read put back in front of the stream
(`PrefixedStream`). The socket stays counted (and the descriptor guard sees it) until trio-websocket closes it.
"""

from __future__ import annotations

import h11
import trio

MAX_HEAD = 16_384  # bytes of an upgrade request's head (request line and headers)
CLOSED = "closed before the upgrade"


class PrefixedStream(trio.abc.Stream):
    """A stream that first returns `prefix`, then what `inner` receives; `closed` is set once it is closed.

    Its repr is the peer's address: trio-websocket reports a stream that is not a socket by its repr
    (`WebSocketConnection.remote`), so the log shows who it is.
    """

    def __init__(self, inner: trio.abc.Stream, prefix: bytes, peer: str = "?") -> None:
        self.inner = inner
        self._prefix = prefix
        self.peer = peer
        self.closed = trio.Event()

    def __repr__(self) -> str:
        return self.peer

    async def send_all(self, data) -> None:
        """Straight to the socket: only the receiving side has bytes to put back."""
        await self.inner.send_all(data)

    async def wait_send_all_might_not_block(self) -> None:
        """Straight to the socket (part of trio's Stream contract)."""
        await self.inner.wait_send_all_might_not_block()

    async def receive_some(self, max_bytes: int | None = None) -> bytes:
        """The bytes read during the upgrade check first, then the socket's, so trio-websocket sees the
        whole request."""
        if self._prefix:
            n = len(self._prefix) if max_bytes is None else max_bytes
            data, self._prefix = self._prefix[:n], self._prefix[n:]
            return data
        return await self.inner.receive_some(max_bytes)

    async def aclose(self) -> None:
        """Close the socket and set `closed`: the hand-over waits for it, so the socket stays counted until
        it is really gone."""
        try:
            await self.inner.aclose()
        finally:
            self.closed.set()


class HandoffListener(trio.abc.Listener):
    """A listener whose `accept` returns the streams passed to `hand_over` (upgrade requests already read)."""

    def __init__(self) -> None:
        self._send, self._recv = trio.open_memory_channel[PrefixedStream](0)

    async def hand_over(self, stream: PrefixedStream) -> None:
        """Pass the stream on and wait until whoever took it has closed it."""
        await self._send.send(stream)
        await stream.closed.wait()

    async def accept(self) -> PrefixedStream:
        """The next stream handed over; trio-websocket's server calls this in its accept loop."""
        return await self._recv.receive()

    async def aclose(self) -> None:
        """Stop taking streams (trio-websocket closes its listeners on shutdown)."""
        await self._recv.aclose()


async def read_upgrade_head(stream: trio.abc.Stream, max_head: int = MAX_HEAD) -> tuple[bytes, h11.Request | str]:
    """Read one request head: (raw bytes, the request) or (raw bytes, why not) when it is not one we take.

    The caller bounds the time. Refusal reasons: the peer closed, the head is malformed or too long, or it is
    not a WebSocket upgrade (a plain GET).
    """
    conn = h11.Connection(h11.SERVER, max_incomplete_event_size=max_head)
    raw = bytearray()
    while True:
        try:
            event = conn.next_event()
        except h11.RemoteProtocolError as exc:
            return bytes(raw), f"bad request: {exc}"
        if isinstance(event, h11.Request):
            headers = {k.lower(): v.lower() for k, v in event.headers}
            if event.method != b"GET" or b"websocket" not in headers.get(b"upgrade", b""):
                return bytes(raw), "not a WebSocket upgrade"
            return bytes(raw), event
        if event is h11.NEED_DATA:
            try:
                data = await stream.receive_some(4096)
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                data = b""
            if not data:
                return bytes(raw), CLOSED
            raw += data
            conn.receive_data(data)
        else:  # ConnectionClosed and the like
            return bytes(raw), CLOSED

