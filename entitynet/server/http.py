"""A small HTTP/1.1 server on trio (h11): a router of path -> handler, bounded in time, size and connections.

Why not prometheus_client's `start_http_server`: it runs a thread per connection and never times out an idle
one, so a few hundred idle sockets are a few hundred threads. This one runs in the server's trio loop, as one
task per connection, with
- `header_timeout`: a new connection must deliver its request within this time, and a later request on a
  kept-alive connection must complete within it once its first byte arrived (slowloris);
- `idle_timeout`: a kept-alive connection with no new request for this long is closed;
- `max_connections`: beyond it a new connection gets 503 and is closed;
- `max_request_bytes`: a request head (or body) beyond it gets 431 (413) and the connection is closed;
- `send_timeout`: a response not taken by the peer within it is abandoned and the connection closed.
Only GET and HEAD are served. The router maps exact paths now; a handler for a path prefix (static files of a
browser viewer) can be added with `Router.add_prefix` without touching the connection logic.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from http import HTTPStatus

import h11
import trio

from entitynet.server import logs
from entitynet.server.fdlimit import Admission


@dataclass
class Response:
    """What a handler returns; the server adds Content-Type and Content-Length itself, so a handler never
    frames bytes."""
    status: int = 200
    body: bytes = b""
    content_type: str = "text/plain; charset=utf-8"
    headers: list[tuple[str, str]] = field(default_factory=list)


Handler = Callable[[h11.Request], "Response | Awaitable[Response]"]


def text(status: int, message: str) -> Response:
    """A plain-text response ending in a newline, for errors and short answers (a terminal prints it cleanly)."""
    return Response(status, (message + "\n").encode())


class Router:
    """path -> handler; the longest matching prefix route is the fallback; otherwise 404."""

    def __init__(self) -> None:
        self._exact: dict[str, Handler] = {}
        self._prefix: list[tuple[str, Handler]] = []

    def add(self, path: str, handler: Handler) -> None:
        """Serve `handler` at exactly `path` (the query string is ignored when matching)."""
        self._exact[path] = handler

    def add_prefix(self, prefix: str, handler: Handler) -> None:
        """Serve `handler` for every path under `prefix` that has no exact route; the longest prefix wins
        (the browser viewer's static files)."""
        self._prefix.append((prefix, handler))
        self._prefix.sort(key=lambda item: -len(item[0]))

    def resolve(self, target: bytes) -> Handler | None:
        """The handler for a request target (query string stripped), or None: the server answers 404."""
        path = target.split(b"?", 1)[0].decode("ascii", "replace")
        handler = self._exact.get(path)
        if handler is None:
            handler = next((h for p, h in self._prefix if path.startswith(p)), None)
        return handler


@dataclass
class HttpLimits:
    """Bounds that keep idle, slow or oversized HTTP clients from holding the server's descriptors and
    memory (each is explained in the module docstring)."""
    header_timeout: float = 5.0
    idle_timeout: float = 15.0
    send_timeout: float = 10.0
    max_connections: int = 64
    max_request_bytes: int = 16_384


class _Close(Exception):
    """End this connection (after an error response where one could be sent)."""


class HttpServer:
    """Serves `router` on streams handed to `handle` (one call per accepted connection; it closes the stream)."""

    def __init__(self, router: Router, limits: HttpLimits | None = None, admission: Admission | None = None,
                 name: str = "http") -> None:
        self.router = router
        self.limits = limits or HttpLimits()
        self.admission = admission
        self.name = name
        self.open = 0  # connections being served now

    async def handle(self, stream: trio.abc.Stream) -> None:
        """Serve one accepted connection to its end and close it; past `max_connections` or the descriptor
        guard it answers 503 at once rather than queueing."""
        lim = self.limits
        admitted = False
        reason = self.admission.enter(client=False) if self.admission is not None else None
        try:
            if reason is None and self.open >= lim.max_connections:
                reason = f"{lim.max_connections} connections open"
            if reason is not None:
                logs.event(f"{self.name} connection refused", logging.DEBUG, reason=reason)
                with trio.move_on_after(min(1.0, lim.send_timeout)):
                    await _send_raw(stream, 503, "busy; try later")
                return
            admitted = True
            self.open += 1
            await self._serve(stream)
        finally:
            if admitted:
                self.open -= 1
            if self.admission is not None:
                self.admission.leave(client=False, admitted=False)
            await trio.aclose_forcefully(stream)

    async def _serve(self, stream: trio.abc.Stream) -> None:
        lim = self.limits
        conn = h11.Connection(h11.SERVER, max_incomplete_event_size=lim.max_request_bytes)
        wait = lim.header_timeout  # the first request: all of it within the header timeout
        try:
            while True:
                request = await self._read_request(conn, stream, wait)
                if request is None:
                    return
                response = await self._respond(request)
                await self._send(conn, stream, request, response)
                if conn.our_state is h11.MUST_CLOSE or conn.their_state is h11.MUST_CLOSE:
                    return
                conn.start_next_cycle()
                wait = lim.idle_timeout
        except _Close:
            return

    async def _read_request(self, conn: h11.Connection, stream: trio.abc.Stream,
                            wait: float) -> h11.Request | None:
        """The next complete request (its body read and bounded), or None when the connection should close."""
        lim = self.limits
        deadline = trio.current_time() + wait
        started = False  # a byte of this request has arrived: from then on the header timeout runs
        request: h11.Request | None = None
        body = 0
        while True:
            try:
                event = conn.next_event()
            except h11.RemoteProtocolError as exc:
                status = exc.error_status_hint
                await self._fail(conn, stream, status, f"bad request: {exc}")
            if event is h11.NEED_DATA:
                if conn.their_state is h11.DONE:  # should not happen: EndOfMessage is returned first
                    return request
                data = b""
                with trio.move_on_at(deadline) as cs:
                    try:
                        data = await stream.receive_some(65_536)
                    except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                        return None
                if cs.cancelled_caught:
                    if started:
                        await self._fail(conn, stream, 408, "request timed out")
                    return None  # idle: close quietly
                if not started and data:
                    started = True
                    deadline = min(deadline, trio.current_time() + lim.header_timeout)
                conn.receive_data(data)
            elif isinstance(event, h11.Request):
                # h11 bounds only a head still incomplete in its buffer; one that arrived whole is measured here
                size = len(event.method) + len(event.target) + sum(len(k) + len(v) + 4 for k, v in event.headers)
                if size > lim.max_request_bytes:
                    await self._fail(conn, stream, 431, "request head too large")
                request = event
            elif isinstance(event, h11.Data):
                body += len(event.data)
                if body > lim.max_request_bytes:
                    await self._fail(conn, stream, 413, "request body too large")
            elif isinstance(event, h11.EndOfMessage):
                return request
            else:  # ConnectionClosed
                return None

    async def _respond(self, request: h11.Request) -> Response:
        if request.method not in (b"GET", b"HEAD"):
            r = text(405, "only GET and HEAD")
            r.headers.append(("Allow", "GET, HEAD"))
            return r
        handler = self.router.resolve(request.target)
        if handler is None:
            return text(404, "not found")
        try:
            result = handler(request)
            if inspect.isawaitable(result):
                result = await result
        except Exception as exc:  # a handler's bug answers 500 and is logged; the server goes on
            logs.event(f"{self.name} handler failed", logging.ERROR, target=request.target, reason=repr(exc))
            return text(500, "internal error")
        return result

    async def _send(self, conn: h11.Connection, stream: trio.abc.Stream, request: h11.Request,
                    response: Response) -> None:
        headers = [("Content-Type", response.content_type), ("Content-Length", str(len(response.body))),
                   *response.headers]
        data = conn.send(h11.Response(status_code=response.status, headers=headers,
                                      reason=HTTPStatus(response.status).phrase.encode()))
        if request.method != b"HEAD":
            data += conn.send(h11.Data(data=response.body))
        data += conn.send(h11.EndOfMessage())
        await self._write(stream, data)

    async def _write(self, stream: trio.abc.Stream, data: bytes) -> None:
        with trio.move_on_after(self.limits.send_timeout) as cs:
            try:
                await stream.send_all(data)
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                raise _Close from None
        if cs.cancelled_caught:
            raise _Close

    async def _fail(self, conn: h11.Connection, stream: trio.abc.Stream, status: int, message: str) -> None:
        """Answer `status` if a response can still be sent, then close."""
        if conn.our_state in (h11.IDLE, h11.SEND_RESPONSE):
            body = (message + "\n").encode()
            try:
                data = conn.send(h11.Response(status_code=status, reason=HTTPStatus(status).phrase.encode(),
                                              headers=[("Content-Type", "text/plain; charset=utf-8"),
                                                       ("Content-Length", str(len(body))),
                                                       ("Connection", "close")]))
                data += conn.send(h11.Data(data=body)) + conn.send(h11.EndOfMessage())
            except h11.LocalProtocolError:
                raise _Close from None
            await self._write(stream, data)
        raise _Close


def error_bytes(status: int, message: str) -> bytes:
    """A complete, closing HTTP/1.1 response with a plain-text body (refusals, outside any h11 state)."""
    body = (message + "\n").encode()
    head = (f"HTTP/1.1 {status} {HTTPStatus(status).phrase}\r\nContent-Type: text/plain; charset=utf-8\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode()
    return head + body


async def _send_raw(stream: trio.abc.Stream, status: int, message: str) -> None:
    try:
        await stream.send_all(error_bytes(status, message))
    except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
        pass
