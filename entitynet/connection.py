"""The client side of protocol v1 over trio: the I/O shell of `entitynet.session.ClientSession`.

Used by the honest client core, viewers and proxies. Every decision (what to replay after a reconnect, the
subscription diff, the clock offset, the backoff, which errors are final, where a REDIRECT moves what) is the
session's; this shell only opens streams, moves frames, sleeps until the session's `next_deadline(now)` and
hands incoming messages to the application. Server-assigned entity ids are per session: every WELCOME (also
after a reconnect) is handed to the consumer, which must then forget the entities it knew.
"""

from __future__ import annotations

import functools
import logging
import math
import ssl
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import trio
import trio_websocket

from entitynet import protocol as P
from entitynet.session import (
    REFUSALS,
    Action,
    Address,
    Answer,
    ClientSession,
    ClockEstimate,
    Connect,
    Deliver,
    Drop,
    Notice,
    ReconnectPolicy,
    Send,
    Stop,
)

log = logging.getLogger("entitynet.connection")

__all__ = ["Connection", "ClockEstimate", "HandshakeRefused", "QueryRefused", "REFUSALS"]

_LOST = (OSError, trio.BrokenResourceError, trio.ClosedResourceError, trio.TooSlowError,
         trio_websocket.HandshakeError, trio_websocket.ConnectionClosed, P.ProtocolError)


class QueryRefused(Exception):
    """The server refused a query (rate limit or bad cells)."""


class HandshakeRefused(Exception):
    """The server refused us for good (wrong protocol version, topology digest or token)."""

    def __init__(self, error: P.Error):
        super().__init__(f"server refused the connection: {error.code} {error.text}")
        self.error = error


@dataclass
class _Stream:
    """One network attempt: its stream, the lock that keeps frames whole, the scope a Drop cancels."""

    address: Address
    scope: trio.CancelScope = field(default_factory=trio.CancelScope)
    lock: trio.Lock = field(default_factory=trio.Lock)
    kind: str = "tcp"
    stream: Any = None
    decoder: P.FrameDecoder | None = None
    reason: str | None = None


class Connection:
    """A reconnecting client connection. Run it with `await nursery.start(conn.run)`.

    `address` is (host, port) for TCP or a ws:// / wss:// URL. Incoming UPDATE/LEAVE/ERROR/REDIRECT/WELCOME
    messages go to `on_message` if given, else to the bounded `incoming` channel (a slow consumer there slows
    only this connection's reading; the server then coalesces for us). `decode` turns a frame's payload into its
    messages (default: the codec's `decode_payload` under `limits`); one that returns and raises the same may be
    shared by many connections (a simulation's viewers: `sims.engine.message_cache`).
    """

    def __init__(
        self,
        address: tuple[str, int] | str,
        digest: str,
        token: str = "",
        *,
        ssl_context: ssl.SSLContext | None = None,
        on_message: Callable[[P.Message], None] | None = None,
        reconnect: bool = True,
        backoff: tuple[float, float] = (0.1, 5.0),
        ping_interval: float = 5.0,
        handshake_timeout: float = 10.0,
        clock: Callable[[], float] = time.time,
        incoming_size: int = 10_000,
        limits: P.CodecLimits = P.DEFAULT_LIMITS,
        alternates: tuple[tuple[str, int] | str, ...] = (),
        failover_s: float = 3.0,
        failover_attempts: int = 2,
        decode: Callable[[bytes], list[P.Message]] | None = None,
        on_frame: Callable[[list[P.Message]], None] | None = None,
    ):
        # alternates: the cluster's other shards, where this client fails over when its shard keeps failing
        # (`failover_attempts` attempts in a row, or for `failover_s`: ClientSession)
        self.session = ClientSession(
            address, digest, token, policy=ReconnectPolicy(backoff[0], backoff[1], reconnect),
            ping_interval=ping_interval, handshake_timeout=handshake_timeout, alternates=tuple(alternates),
            failover_s=failover_s, failover_attempts=failover_attempts)
        self.digest = digest
        self.token = token
        self.ssl_context = ssl_context
        self.on_message = on_message
        self.clock = clock
        self.limits = limits
        # decode: payload -> messages, the codec's decode_payload under `limits` unless given one that returns
        # and raises the same (a simulation's viewers share one that decodes each distinct message once)
        self.decode = decode if decode is not None else functools.partial(P.decode_payload, limits=limits)
        # on_frame: a frame of UPDATEs and LEAVEs on the open link, whole, instead of on_message per message
        # (what the session would do with it: `ClientSession.delivers_whole`); a simulation's viewer fleet
        self.on_frame = on_frame
        self._in_send, self.incoming = trio.open_memory_channel[P.Message](incoming_size)
        self.connected = trio.Event()
        self._streams: dict[int, _Stream] = {}
        self._queries: dict[int, trio.MemorySendChannel] = {}
        self._wake = trio.Event()
        self._nursery: trio.Nursery | None = None
        self._task_status = None
        self._final: BaseException | None = None
        self._stopped = False

    # ------------------------------------------------------------------------------------------ state API
    @property
    def address(self) -> Address:
        """The home shard's address (the given one until a REDIRECT moves us)."""
        return self.session.home

    @property
    def clock_estimate(self) -> ClockEstimate:
        """The session's server-minus-local clock offset estimate."""
        return self.session.clock

    @property
    def welcome(self) -> P.Welcome | None:
        """The home shard's latest WELCOME."""
        return self.session.welcome

    @property
    def connects(self) -> int:
        """How many WELCOMEs this connection has received (1 + reconnects, plus redirect targets)."""
        return self.session.connects

    @property
    def subscriptions(self) -> frozenset[int]:
        """The cells we are subscribed to."""
        return self.session.subscriptions

    def server_time(self) -> float:
        """The server clock now, as well as we know it (the local clock until a PONG has arrived)."""
        return self.session.server_time(self.clock())

    async def publish(self, *msgs: P.Publish) -> None:
        """Publish the state of one or more of our entities (one frame per shard); remembered for replay."""
        await self._apply(self.session.publish(msgs, self.clock()))

    async def unpublish(self, entity: int) -> None:
        """Withdraw one of our entities."""
        await self._apply(self.session.unpublish(entity))

    async def subscribe(self, added: Iterable[int] = (), removed: Iterable[int] = ()) -> None:
        """Add and remove cells from our subscription."""
        await self._apply(self.session.subscribe(added, removed))

    async def camera(self, x: float, y: float, z: float = 0.0) -> None:
        """Tell a sharded server where the viewer's camera is (sent only where WELCOME announced `camera`)."""
        await self._apply(self.session.set_camera(x, y, z))

    async def set_subscription(self, cells: Iterable[int]) -> None:
        """Subscribe to exactly these cells, sending only the difference."""
        await self._apply(self.session.set_subscription(cells))

    async def follow(self, entity: int) -> None:
        """Follow an entity (server id) regardless of cells."""
        await self._apply(self.session.follow(entity))

    async def unfollow(self, entity: int) -> None:
        """Stop following an entity."""
        await self._apply(self.session.unfollow(entity))

    async def set_privacy(self, identity: str | None, audience: Iterable[str] | None = None) -> None:
        """Set our identity and its audience (None = everyone)."""
        await self._apply(self.session.set_privacy(identity, audience))

    async def query(self, kind: str, arg, timeout: float = 5.0) -> P.QueryResult:
        """Ask the server; raises trio.TooSlowError on timeout and QueryRefused on a QUERY_RATE error."""
        send, recv = trio.open_memory_channel(1)
        qid, actions = self.session.query(kind, arg)
        self._queries[qid] = send
        try:
            await self._apply(actions)
            with trio.fail_after(timeout):
                got = await recv.receive()
            if isinstance(got, P.Error):
                raise QueryRefused(f"{got.code} {got.text}")
            return got
        finally:
            self._queries.pop(qid, None)
            self.session.forget_query(qid)

    async def ping(self) -> None:
        """PING the server now (the session also pings every `ping_interval`)."""
        await self._apply(self.session.ping(self.clock()), wake=True)

    # ------------------------------------------------------------------------------------------ running
    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Connect, and reconnect with backoff until cancelled. Raises HandshakeRefused for good refusals;
        returns when the connection is lost with `reconnect=False`."""
        self._task_status = task_status
        self._final, self._stopped = None, False
        async with trio.open_nursery() as nursery:
            self._nursery = nursery
            nursery.start_soon(self._timers)
            await self._apply(self.session.start(self.clock()), wake=True)
        self._nursery = None
        if self._final is not None:
            raise self._final

    async def _timers(self) -> None:
        """Sleep until the session's next deadline (or until an event may have changed it), then run it."""
        while True:
            self._wake = trio.Event()  # replaced before the deadline is read, so no change is missed
            deadline = self.session.next_deadline(self.clock())
            wait = math.inf if deadline is None else max(0.0, deadline - self.clock())
            with trio.move_on_after(wait):
                await self._wake.wait()
            await self._apply(self.session.timers(self.clock()))

    async def _apply(self, actions: list[Action], wake: bool = False) -> None:
        """Carry out the session's actions in order; `wake` when the event may have moved a deadline."""
        on_message = self.on_message
        for a in actions:
            t = type(a)
            if t is Deliver:  # the common case first: a frame of UPDATEs for a viewer
                if on_message is not None:  # called in place: no coroutine per message (issue 11, fan-out)
                    on_message(a.msg)
                else:
                    await self._in_send.send(a.msg)
            elif t is Send:
                await self._write(a.link, a.msgs)
            elif t is Answer:
                ch = self._queries.get(a.query_id)
                if ch is not None:
                    ch.send_nowait(a.msg)
            elif t is Connect:
                if self._nursery is not None:
                    self._nursery.start_soon(self._attempt, a.link, a.address)
            elif t is Drop:
                s = self._streams.get(a.link)
                if s is not None:
                    s.reason = a.reason
                    s.scope.cancel()
            elif t is Notice:
                log.info("%s", a.text)
            elif t is Stop:
                self._stop(a.error)
        self._sync(wake)

    def _sync(self, wake: bool) -> None:
        """Mirror the session's home-link state into `connected`, report `started` once, wake the timers."""
        if self.session.connected:
            self.connected.set()
            if self._task_status is not None:
                self._task_status.started(self)
                self._task_status = None
        elif self.connected.is_set():
            self.connected = trio.Event()
        if wake:
            self._wake.set()

    def _stop(self, error: P.Error | None) -> None:
        if not self._stopped:
            self._stopped = True
            if error is not None:
                self._final = HandshakeRefused(error)
            if self._nursery is not None:
                self._nursery.cancel_scope.cancel()

    async def _attempt(self, link: int, address: Address) -> None:
        """One network attempt: open, HELLO, read frames into the session until the stream ends."""
        s = self._streams[link] = _Stream(address)
        error: str | None = None
        try:
            with s.scope:
                try:
                    s.kind, s.stream = await self._open(address)
                    await self._apply(self.session.connection_made(link, self.clock()), wake=True)
                    on_frame = self.on_frame
                    while True:
                        msgs = await self._next_messages(s)
                        if on_frame is not None and self.session.delivers_whole(link, msgs, self.clock()):
                            on_frame(msgs)  # no deadline moves on a delivery: the timers need no wake
                            continue
                        await self._apply(self.session.receive(link, msgs, self.clock()), wake=True)
                except _LOST as exc:
                    error = str(exc) or type(exc).__name__
            if s.reason is not None:
                error = s.reason
        finally:
            self._streams.pop(link, None)
            if s.stream is not None:
                with trio.CancelScope(shield=True):
                    with trio.move_on_after(1.0):
                        await s.stream.aclose()
        await self._apply(self.session.connection_lost(link, self.clock(), error), wake=True)

    async def _open(self, address: Address):
        if isinstance(address, str):
            return "ws", await trio_websocket.connect_websocket_url(
                self._nursery, address, self.ssl_context, max_message_size=self.limits.max_frame)
        host, port = address
        if self.ssl_context is not None:
            return "tcp", await trio.open_ssl_over_tcp_stream(host, port, ssl_context=self.ssl_context)
        return "tcp", await trio.open_tcp_stream(host, port)

    # ------------------------------------------------------------------------------------------ bytes
    async def _next_messages(self, s: _Stream) -> list[P.Message]:
        if s.kind == "ws":
            data = await s.stream.get_message()
            if not isinstance(data, bytes):
                raise P.ProtocolError(P.ErrorCode.MALFORMED, "text WebSocket message")
            return self.decode(data)
        dec = s.decoder
        if dec is None:
            dec = s.decoder = P.FrameDecoder(self.limits)
        while True:
            payload = dec.next_payload()
            if payload is not None:
                return self.decode(payload)
            data = await s.stream.receive_some(65536)
            if not data:
                raise trio.BrokenResourceError("server closed the connection")
            dec.receive_data(data)

    async def _write(self, link: int, msgs) -> None:
        """Write one frame on attempt `link`; a broken stream is left for its reader to notice (the session
        then replays the remembered state on the next connect)."""
        s = self._streams.get(link)
        if s is None or s.stream is None:
            return
        payload = P.encode_payload(msgs)
        try:
            async with s.lock:
                if s.kind == "ws":
                    await s.stream.send_message(payload)
                else:
                    await s.stream.send_all(P.frame(payload))
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError, trio_websocket.ConnectionClosed):
            pass

