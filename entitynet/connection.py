"""The client side of protocol v1 over trio: one connection that carries many entities.

Used by the honest client core, viewers and proxies. It remembers what it has told the server (the latest
PUBLISH of every entity, the cell subscription, follows, privacy) and replays it after a reconnect, so a
dropped TCP connection costs a moment, not state. Server-assigned entity ids are per session: every WELCOME
(also after a reconnect) is handed to the consumer, which must then forget the entities it knew.

Clock: PING/PONG samples estimate `server clock - local clock`; the sample with the smallest round trip among
the recent ones wins (its error is at most half that round trip).
"""

from __future__ import annotations

import logging
import math
import ssl
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import trio
import trio_websocket

from entitynet import protocol as P

log = logging.getLogger("entitynet.connection")

#: errors after which reconnecting cannot help
REFUSALS = {P.ErrorCode.VERSION_MISMATCH, P.ErrorCode.TOPOLOGY_MISMATCH, P.ErrorCode.AUTH_FAILED}


_LOST = (OSError, trio.BrokenResourceError, trio.ClosedResourceError, trio.TooSlowError,
         trio_websocket.HandshakeError, trio_websocket.ConnectionClosed, P.ProtocolError)


def _leaves(exc: BaseException) -> list[BaseException]:
    """The exceptions inside (nested) exception groups, or [exc]."""
    if isinstance(exc, BaseExceptionGroup):
        return [leaf for e in exc.exceptions for leaf in _leaves(e)]
    return [exc]


class QueryRefused(Exception):
    """The server refused a query (rate limit or bad cells)."""


class HandshakeRefused(Exception):
    """The server refused us for good (wrong protocol version, topology digest or token)."""

    def __init__(self, error: P.Error):
        super().__init__(f"server refused the connection: {error.code} {error.text}")
        self.error = error


@dataclass
class _Sent:
    msg: P.Publish
    at: float  # local clock when published, to shorten the validity when replaying


class ClockEstimate:
    """Server-minus-local clock offset from PING/PONG, best (smallest round trip) of the last samples."""

    def __init__(self, keep: int = 8):
        self.samples: deque[tuple[float, float]] = deque(maxlen=keep)  # (rtt_s, offset_s)

    def add(self, sent_s: float, received_s: float, server_s: float) -> None:
        if not (math.isfinite(sent_s) and math.isfinite(received_s) and math.isfinite(server_s)):
            return
        rtt = received_s - sent_s
        if rtt < 0:
            return  # local clock went backwards: sample is meaningless
        self.samples.append((rtt, server_s - (sent_s + received_s) / 2.0))

    @property
    def offset(self) -> float | None:
        return min(self.samples)[1] if self.samples else None

    @property
    def rtt(self) -> float | None:
        return min(self.samples)[0] if self.samples else None


class Connection:
    """A reconnecting client connection. Run it with `await nursery.start(conn.run)`.

    `address` is (host, port) for TCP or a ws:// / wss:// URL. Incoming UPDATE/LEAVE/ERROR/REDIRECT/WELCOME
    messages go to `on_message` if given, else to the bounded `incoming` channel (a slow consumer there slows
    only this connection's reading; the server then coalesces for us).
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
    ):
        self.address = address
        self.digest = digest
        self.token = token
        self.ssl_context = ssl_context
        self.on_message = on_message
        self.reconnect = reconnect
        self.backoff = backoff
        self.ping_interval = ping_interval
        self.handshake_timeout = handshake_timeout
        self.clock = clock
        self.limits = limits
        self._in_send, self.incoming = trio.open_memory_channel[P.Message](incoming_size)
        self.clock_estimate = ClockEstimate()
        self.welcome: P.Welcome | None = None
        self.connected = trio.Event()
        self.connects = 0
        self._published: dict[int, _Sent] = {}
        self._subs: set[int] = set()
        self._follows: set[int] = set()
        self._privacy: P.Privacy | None = None
        self._stream = None
        self._send_lock = trio.Lock()
        self._queries: dict[int, trio.MemorySendChannel] = {}
        self._next_query = 1
        self._ping_sent: dict[int, float] = {}

    # ------------------------------------------------------------------------------------------ state API
    @property
    def subscriptions(self) -> frozenset[int]:
        return frozenset(self._subs)

    def server_time(self) -> float:
        """The server clock now, as well as we know it (the local clock until a PONG has arrived)."""
        off = self.clock_estimate.offset
        return self.clock() + (off or 0.0)

    async def publish(self, *msgs: P.Publish) -> None:
        """Publish the state of one or more of our entities (one frame)."""
        now = self.clock()
        for m in msgs:
            self._published[m.entity] = _Sent(m, now)
        await self._send(msgs)

    async def unpublish(self, entity: int) -> None:
        self._published.pop(entity, None)
        await self._send([P.Unpublish(entity)])

    async def subscribe(self, added: Iterable[int] = (), removed: Iterable[int] = ()) -> None:
        added, removed = tuple(sorted(set(added))), tuple(sorted(set(removed)))
        self._subs.difference_update(removed)
        self._subs.update(added)
        await self._send([P.Subscribe(added, removed)])

    async def set_subscription(self, cells: Iterable[int]) -> None:
        """Subscribe to exactly these cells, sending only the difference."""
        want = set(cells)
        added, removed = want - self._subs, self._subs - want
        if added or removed:
            await self.subscribe(added, removed)

    async def follow(self, entity: int) -> None:
        self._follows.add(entity)
        await self._send([P.Follow(entity)])

    async def unfollow(self, entity: int) -> None:
        self._follows.discard(entity)
        await self._send([P.Unfollow(entity)])

    async def set_privacy(self, identity: str | None, audience: Iterable[str] | None = None) -> None:
        self._privacy = P.Privacy(identity, None if audience is None else tuple(audience))
        await self._send([self._privacy])

    async def query(self, kind: str, arg, timeout: float = 5.0) -> P.QueryResult:
        """Ask the server; raises trio.TooSlowError on timeout and QueryRefused on a QUERY_RATE error."""
        qid = self._next_query
        self._next_query += 1
        send, recv = trio.open_memory_channel(1)
        self._queries[qid] = send
        try:
            await self._send([P.Query(qid, kind, tuple(arg) if kind == P.QUERY_CELLS else arg)])
            with trio.fail_after(timeout):
                got = await recv.receive()
            if isinstance(got, P.Error):
                raise QueryRefused(f"{got.code} {got.text}")
            return got
        finally:
            self._queries.pop(qid, None)

    async def ping(self) -> None:
        t = self.clock()
        ms = P.now_ms(t)
        self._ping_sent[ms] = t
        if len(self._ping_sent) > 16:
            self._ping_sent.pop(next(iter(self._ping_sent)))
        await self._send([P.Ping(ms)])

    # ------------------------------------------------------------------------------------------ running
    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Connect, and reconnect with backoff until cancelled. Raises HandshakeRefused for good refusals."""
        delay = self.backoff[0]
        self._task_status = task_status
        while True:
            try:
                await self._session()
            except BaseException as exc:  # noqa: B036 - sorted below; anything else propagates unchanged
                leaves = _leaves(exc)
                refused = [e for e in leaves if isinstance(e, HandshakeRefused)]
                if refused:
                    raise refused[0] from None
                if not leaves or not all(isinstance(e, _LOST) for e in leaves):
                    raise
                log.info("connection lost: %s", leaves[0])
            finally:
                if self.connected.is_set():
                    delay = self.backoff[0]
                self._stream = None
                if self.connected.is_set():
                    self.connected = trio.Event()
            if not self.reconnect:
                return
            await trio.sleep(delay)
            delay = min(self.backoff[1], delay * 2)

    async def _open(self):
        if isinstance(self.address, str):
            return "ws", await trio_websocket.connect_websocket_url(
                self._nursery, self.address, self.ssl_context, max_message_size=self.limits.max_frame
            )
        host, port = self.address
        if self.ssl_context is not None:
            return "tcp", await trio.open_ssl_over_tcp_stream(host, port, ssl_context=self.ssl_context)
        return "tcp", await trio.open_tcp_stream(host, port)

    async def _session(self) -> None:
        async with trio.open_nursery() as nursery:
            self._nursery = nursery
            kind, stream = await self._open()
            self._kind = kind
            self._stream = stream
            self._decoder = P.FrameDecoder(self.limits)
            await self._write([P.Hello(P.PROTOCOL_VERSION, self.token, self.digest)])
            with trio.fail_after(self.handshake_timeout):
                first = await self._next_messages()
            welcome = first[0] if first else None
            if isinstance(welcome, P.Error) and welcome.code in REFUSALS:
                raise HandshakeRefused(welcome)
            if not isinstance(welcome, P.Welcome):
                raise P.ProtocolError(P.ErrorCode.MALFORMED, f"expected WELCOME, got {welcome!r:.80}")
            self.welcome = welcome
            self.connects += 1
            async with self._send_lock:
                await self._replay()
                self.connected.set()
            await self._deliver(welcome)
            for m in first[1:]:
                await self._dispatch(m)
            if self._task_status is not None:
                self._task_status.started(self)
                self._task_status = None
            nursery.start_soon(self._pinger)
            while True:
                for m in await self._next_messages():
                    await self._dispatch(m)

    async def _replay(self) -> None:
        """After (re)connecting: privacy, subscription, follows, then every entity's latest state.
        Runs under the send lock, so a publish made meanwhile is either in here or sent right after."""
        msgs: list[P.Message] = []
        if self._privacy is not None:
            msgs.append(self._privacy)
        if self._subs:
            msgs.append(P.Subscribe(tuple(sorted(self._subs)), ()))
        msgs.extend(P.Follow(e) for e in sorted(self._follows))
        now = self.clock()
        for sent in self._published.values():
            m = sent.msg
            left = max(0, m.validity_ms - int(max(0.0, now - sent.at) * 1000))
            msgs.append(P.Publish(m.entity, m.seq, m.cells, left, m.payload))
        for i in range(0, len(msgs), 5000):
            await self._write_raw(msgs[i : i + 5000])

    async def _pinger(self) -> None:
        while True:
            await self.ping()
            await trio.sleep(self.ping_interval)

    async def _dispatch(self, m: P.Message) -> None:
        t = type(m)
        if t is P.Pong:
            sent = self._ping_sent.pop(m.client_ms, None)
            if sent is not None:
                self.clock_estimate.add(sent, self.clock(), m.server_ms / 1000.0)
            return
        if t is P.QueryResult:
            ch = self._queries.get(m.query_id)
            if ch is not None:
                ch.send_nowait(m)
            return
        if t is P.Error:
            if m.code in REFUSALS:
                raise HandshakeRefused(m)
            if m.code in (P.ErrorCode.QUERY_RATE, P.ErrorCode.NO_SUCH_CELL) and self._queries:
                # the server answers queries in order, so a refusal belongs to the oldest one pending
                ch = self._queries.pop(min(self._queries))
                ch.send_nowait(m)  # query() raises QueryRefused
            log.info("server error %s: %s", m.code, m.text)
        await self._deliver(m)

    async def _deliver(self, m: P.Message) -> None:
        if self.on_message is not None:
            self.on_message(m)
        else:
            await self._in_send.send(m)

    # ------------------------------------------------------------------------------------------ bytes
    async def _next_messages(self) -> list[P.Message]:
        if self._kind == "ws":
            data = await self._stream.get_message()
            if not isinstance(data, bytes):
                raise P.ProtocolError(P.ErrorCode.MALFORMED, "text WebSocket message")
            return P.decode_payload(data, self.limits)
        dec = self._decoder
        while True:
            msgs = dec.next_messages()
            if msgs is not None:
                return msgs
            data = await self._stream.receive_some(65536)
            if not data:
                raise trio.BrokenResourceError("server closed the connection")
            dec.receive_data(data)

    async def _write_raw(self, msgs) -> None:
        payload = P.encode_payload(msgs)
        if self._kind == "ws":
            await self._stream.send_message(payload)
        else:
            await self._stream.send_all(P.frame(payload))

    async def _write(self, msgs) -> None:
        async with self._send_lock:
            await self._write_raw(msgs)

    async def _send(self, msgs) -> None:
        """Send now if connected; otherwise the remembered state goes out on the next connect."""
        try:
            async with self._send_lock:
                if self._stream is None or not self.connected.is_set():
                    return
                await self._write_raw(msgs)
        except (trio.BrokenResourceError, trio.ClosedResourceError, OSError, trio_websocket.ConnectionClosed):
            pass  # the reader notices and reconnects; state is replayed then
