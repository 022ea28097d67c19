"""The trio shell around the switchboard core: listeners, per-connection reader and writer, timers.

Reading: bytes -> FrameDecoder (TCP) or one WebSocket message -> decode_payload -> `Switchboard.receive`. A
decode error queues the numbered ERROR and closes that connection only. Plain TCP is read by one task for every
connection (entitynet.server.readhub), TLS and WebSocket by a task each (entitynet.server.reading).

Writing (slow-consumer policy): the core coalesces into each client's outbox (one pending state per entity),
so memory per client is bounded by the entities it can see, whatever the client does. Every `flush_interval`
the flusher drains each client with news into ONE frame and tries to write it at once, synchronously, on the
non-blocking socket (no task switch: that is what makes a thousand viewers cheap). Whatever the kernel does not
take goes to that connection's writer task; while it waits, the outbox keeps coalescing, so a slow reader gets
fewer, newer states and never holds up anyone else. A client whose outbox overflows the core's bounds is sent
SLOW_CONSUMER and closed; a client whose write stays blocked for `stall_timeout` (it stopped reading and the
socket buffers are full) is closed without a goodbye, since its stream is mid-frame. The stall counts only time
the loop could have observed progress (entitynet.server.stall): the server's own freezes are not the client's.
Every frame written stays within the codec's `max_frame` (the limit announced in WELCOME): a larger backlog goes
out as several frames.

Reading: a frame is fed to the core in slices (a SUBSCRIBE or QUERY, whose cost grows with the entities in its
cells, ends a slice), with a checkpoint between slices, so one client's big frame never keeps the others
waiting for long.
"""

from __future__ import annotations

import logging
import math
import signal
import socket
import ssl
import time
from dataclasses import dataclass

import trio
import trio_websocket

from entitynet import protocol as P
from entitynet.server import compiled, fdlimit, logs
from entitynet.server.config import ConfigError, ServerConfig, check_flush_policy, check_ports
from entitynet.server.http import HttpLimits, HttpServer, Router
from entitynet.server.listen import Listeners
from entitynet.server.metrics import Metrics, metrics_handler
from entitynet.server.pacing import Pacer
from entitynet.server.peers import peer_address, throttle_key
from entitynet.server.readhub import ReadHub
from entitynet.server.reading import ReadingMixin
from entitynet.server.stall import StallClock
from entitynet.server.tokens import TokenWatch
from entitynet.server.writing import WritingMixin
from entitynet.switchboard import Outbox, Switchboard, SwitchConfig


@dataclass
class _Conn:
    cid: int
    kind: str  # "tcp" | "ws"
    peer: str
    stream: object
    wake: trio.Event
    outbox: Outbox
    fd: int | None = None  # plain TCP socket: writes are first tried synchronously on it
    scope: trio.CancelScope | None = None
    rest: bytes | None = None  # what the writer task still has to send
    busy: bool = False  # a write is in progress in the writer task
    writing: bool = False  # the writer task holds bytes the kernel has not taken yet ...
    stalled: float = 0.0  # ... and has observed no progress for this long (entitynet.server.stall)
    dirty_since: float | None = None
    closed: bool = False
    # plain TCP: the frame decoder, and the hand-over between the read hub and the reader task (reading.py)
    decoder: P.FrameDecoder | None = None
    handoff: trio.Event | None = None  # set by the hub when the task must take over ...
    pending: tuple | BaseException | None = None  # ... with this: (frame, where to go on), a bug, or None: end


def switch_config_from(config: ServerConfig) -> SwitchConfig:
    """Digest and cell count from the topology artifact or the config; the shell's policies the core enforces
    (the handshake deadline); `config.switch` overrides the limits."""
    digest, n_cells = config.digest, config.n_cells
    if config.topology:
        from topology import artifact

        try:
            topo = artifact.load(config.topology)
        except (OSError, artifact.ArtifactError) as exc:
            raise ConfigError(f"cannot load topology {config.topology}: {exc}") from exc
        digest, n_cells = topo.digest, int(topo.n_cells)
    if digest is None or n_cells is None:
        raise ConfigError("give a topology artifact (or digest and n_cells)")
    overrides = {"handshake_timeout_s": config.handshake_timeout, **config.switch}
    return SwitchConfig(n_cells=n_cells, digest=digest, open_mode=config.open_mode, **overrides)


def _ssl_context(config: ServerConfig) -> ssl.SSLContext | None:
    if not (config.tls_cert or config.tls_key):
        return None
    if not (config.tls_cert and config.tls_key):
        raise ConfigError("TLS needs both --tls-cert and --tls-key")
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    try:
        ctx.load_cert_chain(config.tls_cert, config.tls_key)
    except (OSError, ssl.SSLError) as exc:
        raise ConfigError(f"cannot load TLS certificate/key: {exc}") from exc
    return ctx


STALL_TICK_S = 0.1  # housekeeping's tick while a write is blocked (stall accounting)
IDLE_TICK_S = 1.0  # ... and while none is (the counters on /metrics then lag by up to this)
GAUGES_EVERY_S = 1.0  # the table-size gauges on /metrics are refreshed at most this often


class Server(ReadingMixin, WritingMixin):
    """One shard server. Start it with `await nursery.start(serve, config)` or `entitynet serve`."""

    def __init__(self, config: ServerConfig):
        check_ports(config)
        check_flush_policy(config)
        self.config = config
        self.clock = config.clock
        self.tokens = None if config.open_mode else TokenWatch(config)  # revocations close connections
        # the core asks the token store through this callable; it never opens the store itself
        self.sb = Switchboard(switch_config_from(config), now=self.clock(),
                              authenticate=None if self.tokens is None else self.tokens.authenticate)
        self.metrics = Metrics()
        self.ssl = _ssl_context(config)
        self.conns: dict[int, _Conn] = {}
        self.port: int | None = None
        self.ws_port: int | None = None
        self.metrics_port: int | None = None
        self.http_port: int | None = None  # the browser viewer (entitynet/viewer/routes.py)
        self._nursery: trio.Nursery | None = None
        self._stopping = False
        self.admission = fdlimit.Admission(config.max_clients, config.fd_reserve)
        self.http: HttpServer | None = None  # the metrics HTTP server
        self.viewer_http = self._viewer_http() if config.http_port is not None else None
        self.written = 0  # messages written
        self.frames = 0  # frames written
        self._lat_n = 0
        self._news = trio.Event()  # set when the core has queued something since the last flush (`_note_news`)
        self._news_at = 0.0  # trio time `_news` was set: the latency budget counts from here
        self._filled: trio.Event | None = None  # while the flusher waits out the budget: set once the queue is full
        self._queued_mark = 0  # the core's deliveries + LEAVEs counted at the last flush (`_queue_full`)
        # frames of up to this many states take the short path in _try_write (beyond the outbox bound the
        # long path drops the client)
        self._fast_batch = min(config.max_batch, self.sb.config.max_pending)
        # every frame's payload stays within the announced max_frame: the body (the joined messages) gets at
        # most this many bytes, leaving room for the array header; below `_sure_fit` messages a batch of
        # states fits whatever their sizes (an encoded UPDATE is bounded by the codec limits)
        codec = self.sb.config.codec
        self._max_body = codec.max_frame - 5
        max_update = 64 + codec.max_payload + 5 * codec.max_publish_cells + 4 * codec.max_str
        self._sure_fit = max(1, self._max_body // max_update)
        self._stall_clock = StallClock(max_credit=0.25)
        self._timer_scope: trio.CancelScope | None = None  # the sleep of `_timers`, until `_timer_at` ...
        self._timer_at = math.inf  # ... the core's next deadline (in the core's clock)
        self._tick_scope: trio.CancelScope | None = None  # housekeeping's sleep (`_watch_stalls` shortens it)
        self._tick_idle = True  # ... while it is the long idle tick
        self.cluster = None  # the ClusterLink when config.cluster is set
        self.gc = None  # gcpolicy.FullCollections when config.gc_full_every is set
        self.hub: ReadHub | None = None  # the plain-TCP connections' reader, while `run` runs
        self.pacer: Pacer | None = None  # wake-up pacing when config.pace is set (entitynet/server/pacing.py)

    # ------------------------------------------------------------------------------------------ lifecycle
    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Listen, serve and run the flusher, timers and housekeeping until cancelled (one nursery)."""
        cfg = self.config
        if cfg.open_mode:
            logs.event("OPEN MODE: any token is accepted; use only for local testing", logging.WARNING)
        if cfg.raise_nofile:
            fdlimit.raise_soft_limit()
        try:
            async with trio.open_nursery() as nursery:
                self._nursery = nursery
                self.hub = ReadHub(self._hub_reader())  # before the listeners: it reads their TCP clients
                nursery.start_soon(self.hub.run)
                self.http = self._http_server()
                listen = Listeners(cfg, self.ssl, self.admission, tcp_handler=self._handle_tcp,
                                   ws_handler=self._handle_ws, http=self.http,
                                   max_message=self.sb.config.codec.max_frame, stopping=lambda: self._stopping)
                await listen.open(nursery)
                self.port, self.ws_port, self.metrics_port = listen.port, listen.ws_port, listen.http_port
                if self.viewer_http is not None:
                    self.http_port = await listen.open_http(nursery, cfg.http_port, self.viewer_http)
                self.admission.measure()  # the (raised) limit and what is open besides clients: listeners, ...
                nursery.start_soon(self.admission.watch)
                nursery.start_soon(self._flusher)
                if cfg.pace > 0.0:
                    self.pacer = Pacer(cfg.pace)
                    nursery.start_soon(self.pacer.run)
                nursery.start_soon(self._housekeeping)
                if self.tokens is not None:
                    nursery.start_soon(self._watch_tokens)
                if cfg.gc_full_every is not None:
                    from entitynet.server.gcpolicy import FullCollections

                    self.gc = FullCollections(cfg.gc_full_every, self.metrics.gc_pause.observe)
                    self.gc.start()
                    nursery.start_soon(self.gc.run)  # which restores the collector when the server stops
                nursery.start_soon(self._timers)
                if cfg.cluster is not None:  # sharded: the link to the other switchboards (entitynet.cluster)
                    from entitynet.cluster.link import ClusterLink

                    self.cluster = ClusterLink(self, cfg.cluster)
                    await nursery.start(self.cluster.run)
                compiled.say_if_pure()
                logs.event("listening", host=cfg.host, port=self.port, ws_port=self.ws_port,
                           metrics_port=self.metrics_port, http_port=self.http_port, n_cells=self.sb.config.n_cells,
                           digest=self.sb.config.digest[:16], tls=bool(self.ssl), fd_limit=self.admission.limit)
                task_status.started(self)
        finally:
            logs.event("stopped")

    def _http_server(self) -> HttpServer:
        """The HTTP listener's routes: /metrics now (a viewer's static files can be added to the router)."""
        cfg = self.config
        router = Router()
        router.add("/metrics", metrics_handler(self.metrics.registry))
        limits = HttpLimits(header_timeout=cfg.http_header_timeout, idle_timeout=cfg.http_idle_timeout,
                            max_connections=cfg.http_max_connections, max_request_bytes=cfg.http_max_request)
        return HttpServer(router, limits, self.admission, name="metrics")

    def _viewer_http(self) -> HttpServer:
        """The viewer's routes (and /metrics) for --http-port: entitynet/viewer/routes.py."""
        from entitynet.viewer.routes import viewer_http

        return viewer_http(self)

    async def stop(self) -> None:
        """Graceful shutdown: tell every client SHUTTING_DOWN, let writers flush briefly, then cancel."""
        if self._stopping or self._nursery is None:
            return
        self._stopping = True
        logs.event("shutting down", clients=len(self.conns))
        self.sb.shutdown()
        self._wake_dirty()
        with trio.move_on_after(self.config.shutdown_grace):
            while self.conns:
                await trio.sleep(0.01)
        self._nursery.cancel_scope.cancel()

    # ------------------------------------------------------------------------------------------ connections
    async def _handle_tcp(self, stream, peer: str) -> None:
        """A TCP (or TLS, handshake done) client admitted by `Listeners`; the caller closes the stream."""
        conn = self._open(stream, "tcp", peer, peer_address(stream))
        if isinstance(stream, trio.SocketStream):
            conn.fd = stream.socket.fileno()
            if self.config.sndbuf:
                # a small kernel queue keeps the backlog of a slow reader in the outbox, where a newer state
                # replaces an older one, instead of megabytes of stale states in the socket buffer
                stream.socket.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.config.sndbuf)
        await self._serve(conn, self._read_plain if conn.fd is not None else self._read_tcp)

    async def _handle_ws(self, request) -> None:
        if self._stopping:
            await request.reject(503)
            return
        ws = await request.accept()  # admitted (counted) and its upgrade read by `Listeners`
        conn = self._open(ws, "ws", str(ws.remote), peer_address(ws))
        await self._serve(conn, self._read_ws)

    async def _serve(self, conn: _Conn, read) -> None:
        """Read the connection until it ends, with its writer beside; then close it (TCP and WebSocket alike)."""
        try:
            async with trio.open_nursery() as n:
                conn.scope = n.cancel_scope
                n.start_soon(self._writer, conn)
                await read(conn)
                if not conn.outbox.close_after:
                    n.cancel_scope.cancel()  # peer went away: nothing left to write
                # else the writer sends the ERROR and then cancels (the stall watchdog bounds the wait)
        finally:
            await self._close(conn)

    def _open(self, stream, kind: str, peer: str, addr: tuple[str, int] | None = None) -> _Conn:
        cid = self.sb.connect(self.clock(), peer=throttle_key(addr[0] if addr else None))  # login back-off
        conn = _Conn(cid, kind, peer, stream, trio.Event(), self.sb.outbox(cid))
        self.conns[cid] = conn
        self._rearm()  # its handshake deadline may be the core's earliest
        self.metrics.connections.inc()
        logs.event("connect", logging.DEBUG, cid=cid, kind=kind, peer=peer)
        return conn

    async def _close(self, conn: _Conn) -> None:
        if conn.closed:
            return
        conn.closed = True
        self.conns.pop(conn.cid, None)
        self.sb.disconnect(conn.cid, self.clock())
        self._wake_dirty()
        self.metrics.connections.dec()
        with trio.move_on_after(0.5) as cs:
            cs.shield = True
            try:
                await conn.stream.aclose()
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError,
                    trio_websocket.ConnectionClosed):
                pass
        logs.event("disconnect", logging.DEBUG, cid=conn.cid, kind=conn.kind)

    def _check_stalls(self) -> bool:
        """Credit every blocked write with the time since the last tick and drop those stalled beyond
        `stall_timeout`; returns whether any write is still blocked (the next tick then comes in 0.1 s)."""
        t = time.monotonic()
        limit = self.config.stall_timeout
        credit = self._stall_clock.tick(t)  # a late tick (a frozen loop) credits at most 0.25 s
        blocked = False
        for conn in list(self.conns.values()):
            if not conn.writing:
                continue
            blocked = True
            conn.stalled += credit
            if conn.stalled > limit and conn.scope is not None:
                self.sb.slow_consumer(conn.cid, f"write blocked for {limit:g} s")  # counted with the others
                logs.event("slow consumer dropped", logging.WARNING, cid=conn.cid, peer=conn.peer)
                conn.writing = False
                conn.scope.cancel()
        return blocked

    def _watch_stalls(self) -> None:
        """A write just blocked: if housekeeping sleeps its long idle tick, bring the next tick to 0.1 s from now
        and start the stall credit here (nothing was blocked since the last tick, so nothing is owed)."""
        scope = self._tick_scope
        if scope is not None and self._tick_idle:
            self._tick_idle = False
            self._stall_clock.tick(time.monotonic())
            scope.deadline = min(scope.deadline, trio.current_time() + STALL_TICK_S)

    def _rearm(self) -> None:
        """Wake `_timers` earlier when the core's next deadline moved before the one it sleeps until (a new
        connection's handshake deadline, a short-lived entity). A heap peek: cheap enough for every frame."""
        d = self.sb.next_deadline()
        if d is not None and d < self._timer_at and self._timer_scope is not None:
            self._timer_at = d
            self._timer_scope.deadline = trio.current_time() + max(0.0, d - self.clock())

    async def _timers(self) -> None:
        """Sleep until the core's next deadline (entity expiry or handshake), then let it do what is due: the
        timing rules live in the core (`Switchboard.expire`), the shell only wakes it, instead of polling."""
        sb = self.sb
        while True:
            d = sb.next_deadline()
            with trio.CancelScope() as scope:
                self._timer_scope = scope
                self._timer_at = math.inf if d is None else d
                if d is not None:
                    scope.deadline = trio.current_time() + max(0.0, d - self.clock())
                await trio.sleep_forever()
            self._timer_scope = None
            sb.expire(self.clock())
            self._wake_dirty()  # LEAVEs and handshake ERRORs go out now

    async def _housekeeping(self) -> None:
        """Stall accounting of blocked writes and the metrics: every `STALL_TICK_S` (0.1 s) while a write is
        blocked, else every `IDLE_TICK_S` (1 s; a write that blocks meanwhile brings the tick forward,
        `_watch_stalls`). Why not always 0.1 s: ten wake-ups a second were most of an idle server's CPU (4 ms/s),
        and an idle shard of a cluster pays them too. The table-size gauges are refreshed at most once per
        `GAUGES_EVERY_S` (1 s), however often it ticks (`Switchboard.counts` walks every client)."""
        m, sb = self.metrics, self.sb
        seen_errors: dict[int, int] = {}
        pushed_msgs = pushed_frames = pushed_drops = 0
        blocked, gauges_at = False, -math.inf
        while True:
            self._tick_idle = not blocked
            with trio.move_on_after(STALL_TICK_S if blocked else IDLE_TICK_S) as scope:
                self._tick_scope = scope
                await trio.sleep_forever()
            self._tick_scope = None
            blocked = self._check_stalls()
            self._note_news()  # a slow consumer dropped: its LEAVEs
            now = trio.current_time()
            if now - gauges_at >= GAUGES_EVERY_S:
                gauges_at = now
                counts = sb.counts()
                m.entities.set(counts["entities"])
                m.subscriptions.set(counts["subscriptions"])
                m.follows.set(counts["follows"])
            m.deliveries.inc(self.written - pushed_msgs)
            m.frames_out.inc(self.frames - pushed_frames)
            pushed_msgs, pushed_frames = self.written, self.frames
            drops = sb.stats["slow_consumers"]  # every drop: outbox bounds and blocked writes alike
            m.drops.inc(drops - pushed_drops)
            pushed_drops = drops
            for code, n in sb.errors.items():
                if n > seen_errors.get(code, 0):
                    m.errors.labels(str(code)).inc(n - seen_errors.get(code, 0))
                    seen_errors[code] = n

    async def _watch_tokens(self) -> None:
        """Every `auth_recheck` seconds, the token store's revocations (read off the loop: entitynet.server.tokens)
        close the connections of revoked tokens: AUTH_FAILED queued, the writer closes."""
        assert self.tokens is not None
        while True:
            await trio.sleep(self.config.auth_recheck)
            for cid in await self.tokens.poll(self.sb):
                if cid in self.conns:
                    self._try_write(self.conns[cid])


async def serve(config: ServerConfig, *, task_status=trio.TASK_STATUS_IGNORED) -> None:
    """Run a server until cancelled; `task_status.started(server)` once it listens (ports filled in)."""
    await Server(config).run(task_status=task_status)


async def serve_until_signal(config: ServerConfig) -> None:
    """`entitynet serve`: run until SIGINT/SIGTERM, then shut down gracefully."""
    server = Server(config)  # configuration errors surface here, outside any nursery
    async with trio.open_nursery() as nursery:
        await nursery.start(server.run)
        with trio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
            async for signum in signals:
                logs.event("signal", signal=signal.Signals(signum).name)
                await server.stop()
                break
