"""All of a process's viewer sockets read by one task: one epoll set over every viewer's TCP socket, each ready
socket read once per pass, its frames split and handed on whole.

Why: with a trio task and a `Connection` per viewer, every frame that arrived cost a task wake-up, a
`receive_some`, the connection's read loop and its checks before the frame reached the ghost table; with 300
viewers and 30,000 deliveries a tick that per-frame and per-wake-up work was most of the viewers' side of a
real-time tick (docs/simulation.md, "The coordinator's part"). Here one task waits on one epoll descriptor
(trio waits on it as on any readable descriptor), reads every ready socket once (`recv` on the non-blocking
socket, no task switch), splits the bytes into frames (`FrameDecoder`) and each frame into messages with the
shared decoder (`message_cache.MessageCache`: msgpack's C unpacker finds the messages, each distinct one decoded
once), and hands a frame of UPDATEs and LEAVEs on an open link to the viewer's column of the ghost table whole
(the table queues it and applies the queue in one numpy pass when something reads).

The session duties stay each viewer's own sans-IO `ClientSession`, as in `entitynet.connection.Connection`:
handshake and digest check, SUBSCRIBE differences, PING / PONG, reconnects with backoff and the subscription
replayed, REDIRECT and ERROR. They are rare, so they go through the session's actions here (`_apply`); one
timer task runs every session's deadlines from a heap (no task per viewer). TCP only (the simulation's
loopback); a ws:// address gets a plain `Connection` (`ViewerFleet.connection`).

Bad input costs only its viewer: a malformed or oversized frame, a socket that closes mid-frame, a server that
vanishes end that viewer's attempt as the session decides (it reconnects with backoff), and the reason is kept
per viewer (`errors`, `last_error`); every other viewer's reading goes on.

How it runs: each viewer's `ReaderViewer.run` is started as a `Connection.run` would be; the first one started
hosts the reader (its nursery runs the read and timer tasks and every connection attempt), the others wait for
their session to connect. Cancelling the host ends the reading for all (the shell cancels them together).
"""

from __future__ import annotations

import heapq
import logging
import math
import select
import socket
import time
from collections.abc import Callable

import trio

from entitynet import protocol as P
from entitynet.connection import HandshakeRefused
from entitynet.session import Action, ClientSession, Connect, Deliver, Drop, Notice, ReconnectPolicy, Send, Stop
from sims.engine.message_cache import Frame

log = logging.getLogger("sims.viewer_reader")

READ = 1 << 18  # bytes read from one ready socket per pass (a frame longer than that arrives over passes)


class _Stream:
    """One network attempt of viewer `i`: its socket (the stdlib object and trio's wrapper of it), its
    deframer, and the lock that keeps a written frame whole."""

    __slots__ = ("i", "link", "sock", "tsock", "decoder", "lock", "closed")

    def __init__(self, i: int, link: int, limits: P.CodecLimits) -> None:
        self.i, self.link = i, link
        self.sock: socket.socket | None = None
        self.tsock = None
        self.decoder = P.FrameDecoder(limits)
        self.lock = trio.Lock()
        self.closed = False


class ReaderViewer:
    """Viewer `i` of a `ViewerReader`: what the simulation calls on a viewer's `Connection` (`session`,
    `subscribe`, `camera`, `run`)."""

    def __init__(self, reader: ViewerReader, i: int, session: ClientSession) -> None:
        self.reader, self.i, self.session = reader, i, session

    @property
    def connected(self) -> bool:
        """Whether the session's home link is open."""
        return self.session.connected

    async def subscribe(self, added=(), removed=()) -> None:
        """Add and remove cells from the viewer's subscription."""
        await self.reader._apply(self.i, self.session.subscribe(added, removed))

    async def camera(self, x: float, y: float, z: float = 0.0) -> None:
        """Tell a sharded server where the camera is."""
        await self.reader._apply(self.i, self.session.set_camera(x, y, z))

    async def run(self, task_status=trio.TASK_STATUS_IGNORED) -> None:
        """Connect (the session's dial, handshake, reconnects) and stay until cancelled; `task_status.started`
        once the session is connected. Raises `HandshakeRefused` for a final refusal, as `Connection.run`."""
        await self.reader._run_viewer(self.i, task_status)


class ViewerReader:
    """Many viewers' sessions and sockets under one read task (see the module docstring). `decode(payload)`
    gives a frame's messages (the shared `MessageCache.decode`); `on_frame(i)` and `on_message(i)` give viewer
    i's callbacks for a whole frame of UPDATEs and LEAVEs and for any other message the session delivers."""

    def __init__(self, decode: Callable[[bytes], list[P.Message]],
                 on_frame: Callable[[int], Callable[[list[P.Message]], None]],
                 on_message: Callable[[int], Callable[[P.Message], None]],
                 clock: Callable[[], float] = time.time, limits: P.CodecLimits = P.DEFAULT_LIMITS) -> None:
        self.decode, self._frame_of, self._message_of = decode, on_frame, on_message
        self.clock, self.limits = clock, limits
        self.sessions: list[ClientSession] = []
        self.viewers: list[ReaderViewer] = []
        self._frames: list[Callable] = []
        self._messages: list[Callable] = []
        self._streams: dict[tuple[int, int], _Stream] = {}
        self._by_fd: dict[int, _Stream] = {}
        self._ep: select.epoll | None = None
        self._nursery: trio.Nursery | None = None
        self._up: list[trio.Event] = []
        self._ended: list[trio.Event] = []
        self._final: list[BaseException | None] = []
        self._heap: list[tuple[float, int]] = []
        self._due: list[float | None] = []
        self._wake = trio.Event()
        self._running = False
        self._closed = trio.Event()
        self.errors: list[int] = []  # per viewer: attempts ended by an error (bad frame, broken socket, ...)
        self.last_error: list[str | None] = []  # per viewer: the latest such error, as the session was told
        self.passes = 0  # read passes (epoll wake-ups with something ready)
        self.reads = 0  # socket reads that brought bytes

    def error_report(self, most: int = 20) -> dict:
        """The viewers' connection errors for a run's report: how many attempts ended by an error, on how many
        viewers, and the latest error of the first `most` of those viewers (by index; bounded so that a run
        of 1,000 viewers against a vanished server writes a short report)."""
        bad = [i for i, n in enumerate(self.errors) if n]
        return {"errors": sum(self.errors), "viewers_with_errors": len(bad),
                "last_error": {str(i): self.last_error[i] for i in bad[:most]}}

    # ---- building ----------------------------------------------------------------------------------------------
    def viewer(self, address, digest: str, token: str = "", *, reconnect: bool = True,
               backoff: tuple[float, float] = (0.1, 5.0), ping_interval: float = 5.0,
               handshake_timeout: float = 10.0, alternates: tuple = (), failover_s: float = 3.0,
               failover_attempts: int = 2) -> ReaderViewer:
        """The next viewer's handle, its session built as `Connection` builds one (the same options)."""
        i = len(self.sessions)
        session = ClientSession(address, digest, token, policy=ReconnectPolicy(backoff[0], backoff[1], reconnect),
                                ping_interval=ping_interval, handshake_timeout=handshake_timeout,
                                alternates=tuple(alternates), failover_s=failover_s,
                                failover_attempts=failover_attempts)
        self.sessions.append(session)
        self._frames.append(self._frame_of(i))
        self._messages.append(self._message_of(i))
        self._up.append(trio.Event())
        self._ended.append(trio.Event())
        self._final.append(None)
        self._due.append(None)
        self.errors.append(0)
        self.last_error.append(None)
        self.viewers.append(ReaderViewer(self, i, session))
        return self.viewers[i]

    # ---- the bytes (sans-IO: tests feed it directly) -------------------------------------------------------------
    def take(self, i: int, link: int, decoder: P.FrameDecoder, data: bytes,
             now: float) -> tuple[list[Action], P.ProtocolError | None]:
        """Bytes from viewer `i`'s attempt `link`: every whole frame delivered (a frame of UPDATEs and LEAVEs on
        the open link to `on_frame` whole, any other through the session, its deliveries to `on_message`).
        Returns the session's other actions for the shell, and the error of a bad frame (None: none), which
        ends the attempt: the frames before it are taken and their actions returned (a WELCOME before it
        still opens the link). Consecutive whole frames of one read go on as one: the ghost table takes a
        queue in order (a pair seen twice applies the queue first), so joined frames give what frame by frame
        gives, with one call chain per read instead of per frame."""
        decoder.receive_data(data)
        session, out, run = self.sessions[i], [], None
        try:
            while True:
                payload = decoder.next_payload()
                if payload is None:
                    return out, None
                msgs = self.decode(payload)
                if session.delivers_whole(link, msgs, now):
                    if type(msgs) is Frame:  # the read's run of whole frames goes on as one
                        if run is None:
                            run = msgs  # the decoder's own new list: extended in place
                        else:
                            run.extend(msgs)
                            run.nbytes += msgs.nbytes
                    else:
                        run = self._hand(i, run)
                        self._frames[i](msgs)
                    continue
                run = self._hand(i, run)
                on_message = self._messages[i]
                for a in session.receive(link, msgs, now):
                    if type(a) is Deliver:
                        on_message(a.msg)
                    else:
                        out.append(a)
        except P.ProtocolError as exc:
            return out, exc
        finally:
            self._hand(i, run)

    def _hand(self, i: int, run: Frame | None) -> None:
        """A read's run of whole frames to viewer i's `on_frame` as one frame (None: nothing)."""
        if run is not None:
            self._frames[i](run)

    # ---- running -------------------------------------------------------------------------------------------------
    async def _run_viewer(self, i: int, task_status) -> None:
        if not self._running:
            self._running = True
            try:
                async with trio.open_nursery() as nursery:
                    self._nursery = nursery
                    self._ep = select.epoll()
                    nursery.start_soon(self._read_loop)
                    nursery.start_soon(self._timer_loop)
                    await self._follow(i, task_status)
                    await trio.sleep_forever()  # the other viewers read on until the host is cancelled
            finally:
                self._close_all()
            return
        await self._follow(i, task_status)

    async def _follow(self, i: int, task_status) -> None:
        """Start viewer i's session, report it started once connected, then stay until it ends or the reader
        closes."""
        await self._apply(i, self.sessions[i].start(self.clock()))
        await _either(self._up[i], self._ended[i])
        if self._final[i] is not None:
            raise self._final[i]
        task_status.started(self.viewers[i])
        await _either(self._ended[i], self._closed)
        if self._final[i] is not None:
            raise self._final[i]

    def _close_all(self) -> None:
        for s in list(self._streams.values()):
            self._shut(s)
        if self._ep is not None:
            self._ep.close()
            self._ep = None
        self._nursery = None
        self._running = False
        self._closed.set()

    async def _read_loop(self) -> None:
        """The one reading task: wait for the epoll set, read each ready socket once, hand its frames on."""
        ep, by_fd, clock = self._ep, self._by_fd, self.clock
        while True:
            await trio.lowlevel.wait_readable(ep.fileno())
            ready = ep.poll(0)
            if not ready:
                continue
            self.passes += 1
            now = clock()
            for fd, _ in ready:
                s = by_fd.get(fd)
                if s is None or s.closed:
                    continue
                try:
                    data = s.sock.recv(READ)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError as exc:
                    await self._lose(s, str(exc) or type(exc).__name__)
                    continue
                if not data:
                    what = " mid-frame" if s.decoder.mid_frame else ""
                    await self._lose(s, f"server closed the connection{what}")
                    continue
                self.reads += 1
                rest, bad = self.take(s.i, s.link, s.decoder, data, now)
                if rest:
                    await self._apply(s.i, rest)
                if bad is not None:
                    await self._lose(s, str(bad))

    async def _timer_loop(self) -> None:
        """Every session's deadlines (handshake timeouts, reconnects, PINGs) from one heap."""
        heap, due = self._heap, self._due
        while True:
            self._wake = trio.Event()
            now = self.clock()
            while heap and heap[0][0] <= now:
                d, i = heapq.heappop(heap)
                if due[i] != d:
                    continue  # superseded by a later schedule
                due[i] = None
                await self._apply(i, self.sessions[i].timers(now))
            wait = heap[0][0] - self.clock() if heap else math.inf
            with trio.move_on_after(max(wait, 0.0)):
                await self._wake.wait()

    def _schedule(self, i: int) -> None:
        """Viewer i's next deadline into the heap (the timer task woken when it comes first)."""
        d = self.sessions[i].next_deadline(self.clock())
        if d is None or d == self._due[i]:
            return
        self._due[i] = d
        first = not self._heap or d < self._heap[0][0]
        heapq.heappush(self._heap, (d, i))
        if first:
            self._wake.set()

    async def _apply(self, i: int, actions: list[Action]) -> None:
        """Carry out viewer i's session actions in order (as `Connection._apply` does)."""
        for a in actions:
            t = type(a)
            if t is Deliver:
                self._messages[i](a.msg)
            elif t is Send:
                await self._write(i, a.link, a.msgs)
            elif t is Connect:
                if self._nursery is not None:
                    self._nursery.start_soon(self._attempt, i, a.link, a.address)
            elif t is Drop:
                s = self._streams.get((i, a.link))
                if s is not None:
                    await self._lose(s, a.reason, counted=False)
            elif t is Notice:
                log.info("viewer %d: %s", i, a.text)
            elif t is Stop:
                if a.error is not None:
                    self._final[i] = HandshakeRefused(a.error)
                for s in [s for s in self._streams.values() if s.i == i]:
                    self._shut(s)
                self._ended[i].set()
        if self.sessions[i].connected:
            self._up[i].set()
        self._schedule(i)

    async def _attempt(self, i: int, link: int, address) -> None:
        """One network attempt: connect, register the socket with the epoll set, say HELLO (the session)."""
        s = self._streams[(i, link)] = _Stream(i, link, self.limits)
        try:
            if isinstance(address, str):
                raise OSError(f"the one-reader viewers take TCP addresses only, not {address}")
            host, port = address
            fam, kind, proto, _, sockaddr = (await trio.socket.getaddrinfo(host, port, type=socket.SOCK_STREAM))[0]
            raw = socket.socket(fam, kind, proto)
            s.sock, s.tsock = raw, trio.socket.from_stdlib_socket(raw)  # non-blocking from here
            raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            await s.tsock.connect(sockaddr)
        except OSError as exc:
            await self._lose(s, str(exc) or type(exc).__name__)
            return
        if s.closed or self._ep is None:
            return
        self._by_fd[raw.fileno()] = s
        self._ep.register(raw.fileno(), select.EPOLLIN)
        await self._apply(i, self.sessions[i].connection_made(link, self.clock()))

    async def _write(self, i: int, link: int, msgs) -> None:
        """One frame on viewer i's attempt `link`; a broken socket is left for the reader to notice."""
        s = self._streams.get((i, link))
        if s is None or s.closed or s.tsock is None:
            return
        view = memoryview(P.frame(P.encode_payload(msgs)))
        try:
            async with s.lock:
                while view and not s.closed:
                    view = view[await s.tsock.send(view):]
        except (OSError, trio.ClosedResourceError, trio.BusyResourceError):
            pass

    def _shut(self, s: _Stream) -> None:
        """Close an attempt's socket and forget it (no session event)."""
        if s.closed:
            return
        s.closed = True
        self._streams.pop((s.i, s.link), None)
        if s.sock is not None:
            fd = s.sock.fileno()
            if self._by_fd.get(fd) is s:
                del self._by_fd[fd]
                if self._ep is not None:
                    self._ep.unregister(fd)
            s.tsock.close()

    async def _lose(self, s: _Stream, why: str, counted: bool = True) -> None:
        """Attempt `s` ended: close it and tell its session (which schedules the reconnect); `counted`: an error
        of the attempt's own (not a Drop the session asked for)."""
        if s.closed:
            return
        self._shut(s)
        self.errors[s.i] += counted
        self.last_error[s.i] = why
        await self._apply(s.i, self.sessions[s.i].connection_lost(s.link, self.clock(), why))


async def _either(a: trio.Event, b: trio.Event) -> None:
    """Wait until either event is set."""
    async with trio.open_nursery() as nursery:
        async def wait(ev: trio.Event) -> None:
            await ev.wait()
            nursery.cancel_scope.cancel()
        nursery.start_soon(wait, a)
        nursery.start_soon(wait, b)

