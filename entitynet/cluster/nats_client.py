"""A small trio NATS client over the sans-IO codec (entitynet.cluster.nats_proto): publish, subscribe,
request with a reply inbox, and failover between the nodes of a NATS cluster.

Why this shape: the cluster core is synchronous and sans-IO, so a message handler is a plain callable run in
the reader task (no task per message); publishing only appends to a buffer that one writer task flushes, so
a switchboard's hot path never awaits the network (many PUBs go out in one write). When the connection to a
node is lost the client dials the next known node (the given list plus the `connect_urls` the cluster
announces in INFO), re-sends every SUB and keeps what was published meanwhile, up to `max_pending` bytes
(beyond that new publications are dropped and counted: entity states are superseded within a validity period
anyway). `on_reconnect` tells the owner, which re-requests snapshots; `on_disconnect` tells it the connection
it had is gone (once per loss: failed attempts to reconnect are only logged at DEBUG), so the owner can say so.

`echo: false` in CONNECT: NATS never delivers a switchboard's own publications back to it.

The first connection retries refused ports until its deadline (a server may be starting) and then fails with
`NatsUnreachableError`, naming the URLs, the deadline and the last attempt's failure; a server that refuses our
credentials fails it at once (`NatsAuthorizationError`): a wrong token stays wrong.
"""

from __future__ import annotations

import itertools
import logging
import os
import secrets
import ssl
from collections.abc import Callable, Iterable, Sequence
from urllib.parse import urlsplit

import trio

from entitynet.cluster import nats_proto as N
from entitynet.cluster.defaults import CONNECT_TIMEOUT_S

log = logging.getLogger("entitynet.cluster.nats")

Handler = Callable[[str, str | None, bytes], None]


class NatsConnectionLost(trio.BrokenResourceError):
    """A flush whose connection was lost before the server answered: what was written on it may be lost."""


class NatsConnectFailed(ConnectionError):
    """The first connection failed for good, and the text says why in one line. A ConnectionError (an OSError)
    so that the callers' "cannot reach NATS" reporting takes it as it is; raised bare, never in a group."""


class NatsAuthorizationError(NatsConnectFailed):
    """The server refused our credentials on the first connection (-ERR 'Authorization Violation')."""


class NatsUnreachableError(NatsConnectFailed):
    """No server completed the handshake within the first connection's deadline (it was a bare TooSlowError in
    a nursery's group, which no caller could report: `entitynet serve --cluster` ended in a traceback)."""


#: -ERR texts (lower case) by which nats-server refuses credentials
AUTH_REFUSALS = ("authorization violation",)


class _Flush:
    """One PING waiting for its PONG; `ok` stays False when the connection is lost first."""

    __slots__ = ("event", "ok")

    def __init__(self) -> None:
        self.event = trio.Event()
        self.ok = False


def _server_items(spec: str | Sequence[str]) -> list[str]:
    """The entries of a server list as given (`a,b` or a list), stripped, empty ones dropped."""
    items = spec.split(",") if isinstance(spec, str) else list(spec)
    return [item.strip() for item in items if item.strip()]


def parse_servers(spec: str | Sequence[str]) -> list[tuple[str, int]]:
    """`nats://h1:4222,nats://h2:4222` (or a list) -> [(host, port)]; raises ValueError on a bad entry."""
    out = []
    for item in _server_items(spec):
        u = urlsplit(item if "://" in item else f"nats://{item}")
        if u.scheme not in ("nats", "tls") or not u.hostname:
            raise ValueError(f"bad NATS server {item!r}: expected nats://HOST:PORT")
        out.append((u.hostname, u.port or 4222))
    if not out:
        raise ValueError("no NATS server given")
    return out


def _shown(url: str) -> str:
    """A server URL as an error message may show it: a `user:password@` in it (ignored here: the token is
    its own option) is dropped, so a refusal printed to a log or a terminal carries no secret."""
    scheme, sep, rest = url.rpartition("://")
    return f"{scheme}{sep}{rest.rpartition('@')[2]}"


class NatsClient:
    """Use as `async with NatsClient(servers, name=...) as nc:` (connects, runs reader and writer)."""

    def __init__(self, servers: str | Sequence[str], name: str = "entitynet", token: str | None = None,
                 tls: ssl.SSLContext | None = None, max_pending: int = 64 << 20, reconnect_wait: float = 0.1,
                 connect_timeout: float = CONNECT_TIMEOUT_S, on_reconnect: Callable[[], None] | None = None,
                 on_disconnect: Callable[[str], None] | None = None, on_batch: Callable[[], None] | None = None):
        self.servers = parse_servers(servers)
        self.urls = ",".join(map(_shown, _server_items(servers)))  # for error messages: less any user:password@
        self.name = name
        self.token = token
        self.tls = tls
        self.max_pending = max_pending
        self.reconnect_wait = reconnect_wait
        self.connect_timeout = connect_timeout
        self.on_reconnect = on_reconnect
        self.on_disconnect = on_disconnect  # called with why, once, when an established connection ends
        # called once after the messages of one read from the socket were dispatched (also when a malformed one
        # ends the read): what handlers would otherwise do per message (wake a flusher) is done once per read
        self.on_batch = on_batch
        self._lost_why: str | None = None  # what ended the current connection (reader or writer)
        self.writes = 0  # socket writes (each carries every publication queued since the last)
        self.info: dict = {}
        self.connected = False
        self.reconnects = 0
        self.dropped = 0  # publications dropped while the buffer was over max_pending
        self.published = 0
        self.received = 0
        self.server: tuple[str, int] | None = None
        self._subs: dict[int, tuple[str, Handler]] = {}
        self._sid = itertools.count(1)
        self._out = bytearray()
        self._wake = trio.Event()
        self._pongs: list[_Flush] = []
        self._stream: trio.abc.Stream | None = None
        self._fd: int | None = None  # the plain TCP connection's descriptor (`write_now`), None over TLS or offline
        self._writing = False  # the writer task is inside a send: nobody else may write to the socket
        self._nursery: trio.Nursery | None = None
        self._connected_ev = trio.Event()
        self._refused: NatsAuthorizationError | None = None  # the first connection's credentials were refused
        self._first_failure: str | None = None  # why the last attempt of the first connection failed
        self._closed = False
        self._inbox_prefix = f"_INBOX.{secrets.token_hex(8)}"
        self._requests: dict[str, Handler] = {}
        self._inbox_sid: int | None = None
        self._req = itertools.count(1)

    # ------------------------------------------------------------------------------------------ lifecycle
    async def __aenter__(self) -> NatsClient:
        self._nursery_cm = trio.open_nursery()
        self._nursery = await self._nursery_cm.__aenter__()
        self._nursery.start_soon(self._run)
        deadline = self.connect_timeout * max(2, len(self.servers)) + 1
        try:
            with trio.fail_after(deadline):
                await self._connected_ev.wait()
        except BaseException as exc:  # cancelled or timed out while connecting: close the nursery we opened
            self._closed = True
            self._nursery.cancel_scope.cancel()
            if not isinstance(exc, trio.TooSlowError):
                await self._nursery_cm.__aexit__(type(exc), exc, exc.__traceback__)
                raise
            await self._nursery_cm.__aexit__(None, None, None)  # `_run` was only cancelled: nothing to raise
            last = f" (last try: {self._first_failure})" if self._first_failure else ""
            raise NatsUnreachableError(f"no NATS server answered at {self.urls} within {deadline:g} s{last}") from None
        if self._refused is not None:  # `_run` has returned: the nursery closes at once, with nothing to raise
            self._closed = True
            await self._nursery_cm.__aexit__(None, None, None)
            raise self._refused
        return self

    async def __aexit__(self, *exc) -> bool | None:
        await self.close()
        return await self._nursery_cm.__aexit__(*exc)

    async def close(self) -> None:
        """Stop: the session's own cleanup closes the stream."""
        self._closed = True
        if self._nursery is not None:
            self._nursery.cancel_scope.cancel()

    def _known(self) -> list[tuple[str, int]]:
        known = list(self.servers)
        for url in self.info.get("connect_urls") or ():
            try:
                for hp in parse_servers(url):
                    if hp not in known:
                        known.append(hp)
            except ValueError:
                continue
        return known

    async def _run(self) -> None:
        first = True
        while not self._closed:
            for host, port in self._known():
                self._lost_why = None
                try:
                    await self._session(host, port, first)
                except (OSError, trio.BrokenResourceError, trio.ClosedResourceError, trio.TooSlowError,
                        N.NatsProtocolError, ssl.SSLError) as exc:
                    if first and isinstance(exc, NatsAuthorizationError):  # never connected: stop trying
                        self._refused = exc
                        self._connected_ev.set()
                        return
                    self._lost_why = self._lost_why or str(exc) or type(exc).__name__
                    if first and not self.connected:
                        self._first_failure = self._attempt_failure(host, port, exc)
                    log.debug("NATS connection to %s:%s ended or failed: %s", host, port, exc)
                if self.connected:
                    first = False
                    if self.on_disconnect is not None and not self._closed:
                        self.on_disconnect(self._lost_why or "the server closed the connection")
                self.connected = False
                self._stream = None
                for f in self._pongs:  # nobody will answer these: their flushes fail
                    f.event.set()
                self._pongs.clear()
                if self._closed:
                    return
                await trio.sleep(self.reconnect_wait)

    def _attempt_failure(self, host: str, port: int, exc: BaseException) -> str:
        """One failed attempt in words, with the server it was made to: trio's `open_tcp_stream` says only "all
        attempts to connect to ... failed" and keeps each address's own error (Connection refused, ...) in its
        cause; an attempt that hung is a bare TooSlowError."""
        cause = exc.__cause__
        if isinstance(cause, BaseExceptionGroup) and isinstance(cause.exceptions[0], OSError):
            leaf = cause.exceptions[0]
            why = os.strerror(leaf.errno) if leaf.errno else str(leaf)
        elif isinstance(exc, trio.TooSlowError):
            why = f"no answer within {self.connect_timeout:g} s"
        else:
            why = str(exc) or type(exc).__name__
        return f"{host}:{port}: {why}"

    async def _session(self, host: str, port: int, first: bool) -> None:
        with trio.fail_after(self.connect_timeout):
            stream: trio.abc.Stream = await trio.open_tcp_stream(host, port)
            parser = N.Parser()
            info = await self._read_info(stream, parser)
            if self.tls is not None or info.get("tls_required"):
                if self.tls is None:
                    raise N.NatsProtocolError("the NATS server requires TLS: give a TLS context")
                stream = trio.SSLStream(stream, self.tls, server_hostname=host)
                await stream.do_handshake()
            opts = {"verbose": False, "pedantic": False, "echo": False, "name": self.name, "lang": "python-trio",
                    "version": "0.1", "protocol": 1, "headers": False, "no_responders": False}
            if self.token:
                opts["auth_token"] = self.token
            hello = N.connect(opts)
            for sid, (subject, _h) in self._subs.items():
                hello += N.sub(subject, sid)
            await stream.send_all(hello + N.PING)
            while True:  # the PONG to our PING means CONNECT and every SUB were accepted
                ev = await self._next(stream, parser)
                if isinstance(ev, N.Err) and ev.text.lower().startswith(AUTH_REFUSALS):
                    raise NatsAuthorizationError(f"NATS at {host}:{port} refused the credentials ({ev.text}): "
                                                 "a wrong or missing token")
                if isinstance(ev, N.Err):
                    raise N.NatsProtocolError(f"NATS refused the connection: {ev.text}")
                if isinstance(ev, N.Pong):
                    break
                if isinstance(ev, N.Ping):
                    await stream.send_all(N.PONG)
                elif isinstance(ev, N.Msg):
                    self._dispatch(ev)
        self.info, self._stream, self.server, self.connected = info, stream, (host, port), True
        self._fd = stream.socket.fileno() if isinstance(stream, trio.SocketStream) else None
        if self.on_batch is not None:
            self.on_batch()  # messages that arrived with the handshake's PONG were dispatched
        if not first:
            self.reconnects += 1
            log.debug("NATS reconnected to %s:%s", host, port)
            if self.on_reconnect is not None:
                self.on_reconnect()
        self._connected_ev.set()
        self._wake.set()
        try:
            async with trio.open_nursery() as n:  # neither task raises a lost connection: it just ends
                n.start_soon(self._writer, stream, n.cancel_scope)
                await self._reader(stream, parser)
                n.cancel_scope.cancel()
        finally:
            self._fd = None
            with trio.CancelScope(shield=True), trio.move_on_after(0.2):
                try:
                    await stream.aclose()
                except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                    pass

    async def _read_info(self, stream, parser: N.Parser) -> dict:
        ev = await self._next(stream, parser)
        if not isinstance(ev, N.Info):
            raise N.NatsProtocolError(f"expected INFO, got {ev!r:.60}")
        return ev.info

    async def _next(self, stream, parser: N.Parser) -> N.Event:
        while (ev := parser.next_event()) is None:
            data = await stream.receive_some(65536)
            if not data:
                raise trio.BrokenResourceError("NATS server closed the connection")
            parser.receive_data(data)
        return ev

    async def _reader(self, stream, parser: N.Parser) -> None:
        """Read until the connection ends. Over plain TCP the reader waits until the socket is readable and
        then reads once: trio's `receive_some` tries the read first (a failed system call and a raised
        exception whenever nothing is there, i.e. on nearly every read of a lightly loaded shard) and passes
        through the scheduler once more after a read that succeeded."""
        try:
            await self._read_loop(stream, parser)
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError, N.NatsProtocolError) as exc:
            self._lost_why = self._lost_why or str(exc) or type(exc).__name__
            log.debug("NATS connection lost: %s", exc)

    async def _read_loop(self, stream, parser: N.Parser) -> None:
        fd = self._fd
        wait = trio.lowlevel.wait_readable
        while True:
            if fd is None:
                data = await stream.receive_some(262144)
            else:  # plain TCP: wait, then one read (as `Server._read_plain` does)
                try:
                    await wait(fd)
                    data = os.read(fd, 262144)
                except BlockingIOError:
                    continue  # readable was reported but nothing was there: wait again
                except OSError as exc:  # reset by the server
                    raise trio.BrokenResourceError(f"read failed: {exc}") from None
            if not data:
                return
            parser.receive_data(data)
            try:
                while (ev := parser.next_event()) is not None:
                    t = type(ev)
                    if t is N.Msg:
                        self._dispatch(ev)
                    elif t is N.Ping:
                        self._send(N.PONG)
                    elif t is N.Pong:
                        if self._pongs:
                            f = self._pongs.pop(0)
                            f.ok = True
                            f.event.set()
                    elif t is N.Err:
                        log.warning("NATS error: %s", ev.text)
                        if "authorization" in ev.text.lower() or "stale" in ev.text.lower():
                            return
                    elif t is N.Info:
                        self.info.update(ev.info)
            finally:
                if self.on_batch is not None:
                    self.on_batch()

    async def _writer(self, stream, scope: trio.CancelScope) -> None:
        try:
            while True:
                await self._wake.wait()
                self._wake = trio.Event()
                while self._out:
                    data = bytes(self._out)
                    self._out.clear()
                    self.writes += 1
                    self._writing = True
                    try:
                        await stream.send_all(data)
                    finally:
                        self._writing = False
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError) as exc:
            self._lost_why = self._lost_why or f"write failed: {exc}"
            log.debug("NATS write failed: %s", exc)
            scope.cancel()  # the reader ends too; the client dials again

    def _dispatch(self, m: N.Msg) -> None:
        self.received += 1
        entry = self._subs.get(m.sid)
        if entry is None:
            return
        try:
            entry[1](m.subject, m.reply, m.payload)
        except Exception:  # a bad message must not take the link down
            log.exception("NATS handler failed on %s", m.subject)

    def _send(self, data: bytes) -> None:
        self._out += data
        self._wake.set()

    # ------------------------------------------------------------------------------------------ API
    def publish(self, subject: str, payload: bytes, reply: str | None = None) -> bool:
        """Queue a publication (no await); False if it was dropped (buffer over `max_pending`)."""
        if not self._queue(subject, payload, reply):
            return False
        self._wake.set()
        return True

    def _queue(self, subject: str, payload: bytes, reply: str | None) -> bool:
        if len(self._out) > self.max_pending:
            self.dropped += 1
            return False
        self.published += 1
        self._out += N.pub(subject, payload, reply)
        return True

    def publish_batch(self, items: Iterable[tuple[str, bytes, str | None]]) -> None:
        """Queue several publications (subject, payload, reply) and write them now (`write_now`): what a shard's
        pump hands over after each latency budget."""
        for subject, payload, reply in items:
            self._queue(subject, payload, reply)
        self.write_now()

    def write_now(self) -> None:
        """Write what is queued from the caller, in one system call, when the connection is plain TCP and the
        writer task is not inside a send (so bytes never interleave); what the socket does not take at once,
        and everything over TLS or while reconnecting, is left to the writer task. Why: waking the writer task
        for each write was a pass of trio's scheduler per NATS write, a large part of a lightly loaded shard's
        CPU; the server's reader answers a PING the same way (docs/switch.md)."""
        if not self._out:
            return
        fd = self._fd
        if fd is None or self._writing:
            self._wake.set()
            return
        try:
            n = os.write(fd, self._out)
        except BlockingIOError:
            n = 0
        except OSError:  # the connection is failing: the writer task finds out, and the client reconnects
            self._wake.set()
            return
        if n:
            self.writes += 1
            del self._out[:n]
        if self._out:
            self._wake.set()

    def subscribe(self, subject: str, handler: Handler) -> int:
        """Remember `handler` for `subject` and return its sid; the SUB is sent now if connected, and every
        remembered subscription is sent again on reconnect."""
        sid = next(self._sid)
        frame = N.sub(subject, sid)  # validates the subject before anything is remembered
        self._subs[sid] = (subject, handler)
        if self.connected:
            self._send(frame)
        return sid

    def unsubscribe(self, sid: int) -> None:
        """Forget a subscription (and UNSUB it if connected); an unknown sid is ignored."""
        if self._subs.pop(sid, None) is not None and self.connected:
            self._send(N.unsub(sid))

    def new_inbox(self, handler: Handler) -> str:
        """A reply subject whose messages go to `handler` (one wildcard SUB serves all requests)."""
        if self._inbox_sid is None:
            self._inbox_sid = self.subscribe(f"{self._inbox_prefix}.*", self._on_inbox)
        subject = f"{self._inbox_prefix}.{next(self._req)}"
        self._requests[subject] = handler
        return subject

    def drop_inbox(self, subject: str) -> None:
        """Stop routing a reply subject to its handler (late replies to it are then dropped)."""
        self._requests.pop(subject, None)

    def _on_inbox(self, subject: str, reply: str | None, payload: bytes) -> None:
        h = self._requests.get(subject)
        if h is not None:
            h(subject, reply, payload)

    async def flush(self, timeout: float = 2.0) -> None:
        """Round trip: every publication and SUB before this call has reached the server. Raises
        `NatsConnectionLost` when the connection drops first (bytes written on it may never have arrived: a
        caller that needs them there publishes them again after the reconnect), `trio.TooSlowError` on timeout."""
        f = _Flush()
        self._pongs.append(f)
        self._send(N.PING)
        with trio.fail_after(timeout):
            await f.event.wait()
        if not f.ok:
            raise NatsConnectionLost("NATS connection lost before the flush was confirmed")
