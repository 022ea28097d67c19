"""The server's listeners and the gate every connection passes before the protocol handler sees it.

For each accepted socket, in order:
1. count it (`Admission.enter`): beyond `max_clients`, or with fewer than `fd_reserve` descriptors left, the
   connection is refused (SERVER_FULL on TCP/TLS, HTTP 503 on the WebSocket port) and closed at once;
2. TLS: handshake within `handshake_timeout`, or log "TLS handshake timed out/failed" with the peer and close;
3. WebSocket: read the upgrade request within `handshake_timeout` (wsgate.py); a client that closes before
   is freed at once, one that is too slow is logged and closed; a complete upgrade goes to trio-websocket;
4. the protocol handler (`Server._handle_tcp`, `Server._handle_ws`) runs; when it returns the socket is
   closed and uncounted.
A connection therefore holds its client slot and its descriptor from accept to close, whatever stage it is in,
and no stage waits longer than the handshake timeout for a peer that does nothing.
"""

from __future__ import annotations

import logging
import ssl
from collections.abc import Awaitable, Callable

import h11
import trio
import trio_websocket

from entitynet import protocol as P
from entitynet.server.accept import HandshakeLog, Throttled, accept_loop, peer_of, tls_handshake
from entitynet.server.config import ListenError, ServerConfig, bind_reason
from entitynet.server.fdlimit import Admission
from entitynet.server.http import HttpServer, error_bytes
from entitynet.server.wsgate import CLOSED, HandoffListener, PrefixedStream, read_upgrade_head

REFUSAL_TIMEOUT = 1.0  # seconds to spend telling a refused client why


class Listeners:
    """Opens the TCP, WebSocket and HTTP listeners of one server and gates their connections."""

    def __init__(self, config: ServerConfig, context: ssl.SSLContext | None, admission: Admission, *,
                 tcp_handler: Callable[[trio.abc.Stream, str], Awaitable[None]],
                 ws_handler: Callable[[trio_websocket.WebSocketRequest], Awaitable[None]],
                 http: HttpServer | None, max_message: int, stopping: Callable[[], bool]) -> None:
        self.config = config
        self.ssl = context
        self.admission = admission
        self.tcp_handler = tcp_handler
        self.ws_handler = ws_handler
        self.http = http
        self.max_message = max_message
        self.stopping = stopping
        self.port: int | None = None
        self.ws_port: int | None = None
        self.http_port: int | None = None
        self._gate: HandoffListener | None = None
        # one line a second for each of these, whatever the flood (`more=N` counts the folded ones)
        self._refused = Throttled("connection refused")
        self._tls_log = HandshakeLog()
        self._upgrade_timed_out = Throttled("WebSocket upgrade timed out", logging.INFO)
        self._upgrade_refused = Throttled("WebSocket upgrade refused", logging.INFO)

    async def open(self, nursery: trio.Nursery) -> None:
        """Bind every configured port (errors surface here) and start accepting."""
        cfg = self.config
        if cfg.port is not None:
            self.port = await self._listen(nursery, cfg.port, self._on_tcp, "port")
        if cfg.ws_port is not None:
            self._gate = HandoffListener()
            server = trio_websocket.WebSocketServer(
                self.ws_handler, [self._gate], max_message_size=self.max_message,
                connect_timeout=cfg.handshake_timeout, disconnect_timeout=min(2.0, cfg.handshake_timeout))
            await nursery.start(server.run)
            self.ws_port = await self._listen(nursery, cfg.ws_port, self._on_ws, "ws_port")
        if cfg.metrics_port is not None and self.http is not None:
            self.http_port = await self._listen(nursery, cfg.metrics_port, self.http.handle, "metrics_port")

    async def open_http(self, nursery: trio.Nursery, port: int, http: HttpServer) -> int:
        """Another HTTP listener (the browser viewer's) on `port`; returns the port bound."""
        return await self._listen(nursery, port, http.handle, "http_port")

    async def _listen(self, nursery: trio.Nursery, port: int, handler, setting: str) -> int:
        """Bind `port` (the config's `setting`) and accept on it; a failure is a ListenError naming both."""
        try:
            listeners = await trio.open_tcp_listeners(port, host=self.config.host)
        except OSError as exc:
            raise ListenError(setting, self.config.host, port, bind_reason(exc)) from exc
        for listener in listeners:
            nursery.start_soon(accept_loop, listener, handler, nursery)
        return listeners[0].socket.getsockname()[1]

    def _refusing(self, reason: str | None, peer: str) -> str | None:
        if reason is None and self.stopping():
            reason = "shutting down"
        if reason is not None:
            self._refused(reason=reason, peer=peer, clients=self.admission.clients)
        return reason

    async def _on_tcp(self, sock: trio.SocketStream) -> None:
        peer = peer_of(sock)
        reason = self.admission.enter(client=True)
        stream: trio.abc.Stream | None = sock
        try:
            if self.ssl is not None:
                timeout = self.config.handshake_timeout if reason is None else REFUSAL_TIMEOUT
                stream = await tls_handshake(sock, self.ssl, timeout, peer, self._tls_log)
                if stream is None:
                    return
            if self._refusing(reason, peer) is not None:
                if reason is not None:  # shutting down: just close, as before
                    code = int(P.ErrorCode.SERVER_FULL)
                    await _send_quietly(stream, P.frame(P.encode_payload([P.Error(code, "server full; try later")])))
                return
            await self.tcp_handler(stream, peer)
        finally:
            self.admission.leave(client=True, admitted=reason is None)
            await trio.aclose_forcefully(stream if stream is not None else sock)

    async def _on_ws(self, sock: trio.SocketStream) -> None:
        peer = peer_of(sock)
        reason = self.admission.enter(client=True)
        stream: trio.abc.Stream | None = sock
        timeout = self.config.handshake_timeout
        try:
            if self.ssl is not None:
                stream = await tls_handshake(sock, self.ssl, timeout if reason is None else REFUSAL_TIMEOUT, peer,
                                             self._tls_log)
                if stream is None:
                    return
            why = self._refusing(reason, peer)
            if why is not None:
                text = "server full; try later" if reason is not None else "shutting down"
                await _send_quietly(stream, error_bytes(503, text))
                return
            with trio.move_on_after(timeout) as cs:
                raw, request = await read_upgrade_head(stream)
            if cs.cancelled_caught:
                self._upgrade_timed_out(peer=peer, timeout_s=f"{timeout:g}")
                return
            if not isinstance(request, h11.Request):
                if request != CLOSED:  # a client that went away is no news
                    self._upgrade_refused(peer=peer, reason=request)
                    await _send_quietly(stream, error_bytes(400, request))
                return
            assert self._gate is not None
            await self._gate.hand_over(PrefixedStream(stream, raw, peer))
        finally:
            self.admission.leave(client=True, admitted=reason is None)
            await trio.aclose_forcefully(stream if stream is not None else sock)


async def _send_quietly(stream: trio.abc.Stream, data: bytes) -> None:
    """Best effort, bounded: the peer may be gone or not reading."""
    with trio.move_on_after(REFUSAL_TIMEOUT):
        try:
            await stream.send_all(data)
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
            pass
