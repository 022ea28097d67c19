"""Accepting connections: an accept loop that survives EMFILE quietly, peer names, the TLS handshake.

Why not `trio.serve_listeners`: on EMFILE/ENFILE/ENOMEM/ENOBUFS it logs an ERROR *with a traceback* every
100 ms and retries; under a descriptor flood that is thousands of tracebacks and nothing the operator can act
on. Here the same condition is one WARNING line per `every` seconds with a count, and the loop backs off the
same way. TLS handshakes are done explicitly, bounded by the handshake timeout, so a peer that never finishes
one is logged as exactly that (and not, later, as a slow consumer when the first write blocks on it).
"""

from __future__ import annotations

import errno
import logging
import os
import ssl
import time
from collections.abc import Awaitable, Callable

import trio

from entitynet.server import logs

CAPACITY_ERRNOS = frozenset({errno.EMFILE, errno.ENFILE, errno.ENOMEM, errno.ENOBUFS})
RETRY_AFTER = 0.1  # seconds to wait after accept failed for lack of resources


class Throttled:
    """Log an event at most once per `every` seconds, with how many were folded into it."""

    def __init__(self, name: str, level: int = logging.WARNING, every: float = 1.0) -> None:
        self.name, self.level, self.every = name, level, every
        self._last = -float("inf")
        self._folded = 0

    def __call__(self, **fields) -> None:
        t = time.monotonic()
        if t - self._last < self.every:
            self._folded += 1
            return
        if self._folded:
            fields["more"] = self._folded  # occurrences since the previous line
        self._folded = 0
        self._last = t
        logs.event(self.name, self.level, **fields)


async def accept_loop(listener: trio.SocketListener, handler: Callable[[trio.SocketStream], Awaitable[object]],
                      nursery: trio.Nursery) -> None:
    """Accept forever, starting `handler(stream)` in `nursery` for each; the handler owns (and closes) it."""
    out_of = Throttled("accept failed; retrying")
    async with listener:
        while True:
            try:
                stream = await listener.accept()
            except OSError as exc:
                if exc.errno not in CAPACITY_ERRNOS:
                    raise
                out_of(errno=errno.errorcode.get(exc.errno, exc.errno), reason=os.strerror(exc.errno),
                       retry_s=RETRY_AFTER)
                await trio.sleep(RETRY_AFTER)
                continue
            nursery.start_soon(handler, stream)


def peer_of(stream: trio.abc.Stream) -> str:
    """'host:port' of the remote end of a socket stream, TLS or not ('?' when unknown)."""
    while isinstance(stream, trio.SSLStream):
        stream = stream.transport_stream
    sock = getattr(stream, "socket", None)
    try:
        addr = sock.getpeername() if sock is not None else None
    except OSError:
        addr = None
    if not addr:
        return "?"
    if isinstance(addr, tuple):
        host, port = addr[0], addr[1]
        return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    return str(addr)


class HandshakeLog:
    """The log lines of failed TLS handshakes, throttled (a flood of them is one line a second, counted)."""

    def __init__(self) -> None:
        self.timed_out = Throttled("TLS handshake timed out", logging.INFO)
        self.failed = Throttled("TLS handshake failed", logging.INFO)


async def tls_handshake(stream: trio.SocketStream, context: ssl.SSLContext, timeout: float,
                        peer: str, log: HandshakeLog) -> trio.SSLStream | None:
    """Wrap and handshake within `timeout`; the TLS stream, or None (logged, socket left to the caller)."""
    tls = trio.SSLStream(stream, context, server_side=True, https_compatible=False)
    with trio.move_on_after(timeout):
        try:
            await tls.do_handshake()
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as exc:
            cause = exc.__cause__ or exc
            log.failed(peer=peer, reason=str(cause) or type(cause).__name__)
            return None
        return tls
    log.timed_out(peer=peer, timeout_s=f"{timeout:g}")
    return None
