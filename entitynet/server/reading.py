"""The server's reading path: a connection's bytes into frames, frames fed to the core in slices, and the
frames that are one PING answered at once.

A mixin of `Server` (entitynet.server.app), split off to keep each module to one job. Reading: bytes ->
FrameDecoder (TCP) or one WebSocket message -> decode_payload -> `Switchboard.receive`. A decode error queues the
numbered ERROR and closes that connection only. A frame is fed to the core in slices (a SUBSCRIBE or QUERY, whose
cost grows with the entities in its cells, ends a slice), and the other clients are served between slices once
they add up to `FEED_YIELD_S` of work, so one client's big frame never keeps the others waiting for long.
"""

from __future__ import annotations

import logging
import os
import time
from typing import TYPE_CHECKING

import trio
import trio_websocket

from entitynet import protocol as P
from entitynet.server import logs

if TYPE_CHECKING:
    from entitynet.server.app import _Conn

#: a client frame fed in slices yields to the others once its slices since the last yield took this long: a
#: checkpoint is a pass through trio's scheduler (tens of microseconds), more than a small SUBSCRIBE costs, so
#: a frame of a few cheap slices (a viewer's SUBSCRIBE difference and its PING) goes through without one
FEED_YIELD_S = 0.0005


class ReadingMixin:
    """Inbound half of `Server`; uses its `sb`, `config`, `tokens`, `metrics`, `clock` and the writing half."""

    async def _feed(self, conn: _Conn, msgs: list[P.Message]) -> None:
        """Feed one frame to the core in slices, serving the other clients between slices: a slice ends after
        `feed_slice` messages or after a SUBSCRIBE or QUERY (their work grows with the entities in the cells),
        and the others are served once the slices since the last yield took `FEED_YIELD_S`.
        A HELLO whose token the core will check is looked up first, off the loop (entitynet.server.tokens), and
        the answer handed over for the first slice, which the core handles without a task switch."""
        sb = self.sb
        tokens, first = self.tokens, msgs[0] if msgs else None
        looked_up, answer = False, None
        if tokens is not None and type(first) is P.Hello and sb.asks_token(conn.cid, first, self.clock()):
            looked_up, answer = True, await tokens.lookup(first.token)
            if sb.outbox(conn.cid) is None:
                return  # it went away (or its handshake timed out) while the store was read
        step = self.config.feed_slice
        start, n = 0, len(msgs)
        began = time.perf_counter()
        while start < n:
            end = start
            limit = min(n, start + step)
            while end < limit:
                t = type(msgs[end])
                end += 1
                if t is P.Subscribe or t is P.Query:
                    break
            before = sb.stats["updates_in"]
            part = msgs[start:end] if start or end < n else msgs
            if start == 0 and looked_up:
                with tokens.answering(first.token, answer):
                    sb.receive(conn.cid, part, self.clock(), frame_end=end >= n)
            else:
                sb.receive(conn.cid, part, self.clock(), frame_end=end >= n)
            if sb.stats["updates_in"] != before:  # a PING or SUBSCRIBE frame costs no Prometheus call
                self.metrics.updates_in.inc(sb.stats["updates_in"] - before)
            self._rearm()
            ob = sb.outbox(conn.cid)
            if ob is not None and (ob.has_control or ob.close_after):
                self._try_write(conn)  # answers (WELCOME, PONG, ERROR) go out now, not at the next flush
                if not conn.busy:
                    sb.written_out(conn.cid)  # all of it went: no flusher wake-up for this client
            self._note_news()
            if ob is None or ob.close_after:
                return
            start = end
            if start < n and time.perf_counter() - began >= FEED_YIELD_S:
                await trio.lowlevel.checkpoint()  # the others' frames and the flusher run here
                began = time.perf_counter()

    def _reject(self, conn: _Conn, err: P.ProtocolError) -> None:
        logs.event("protocol error", logging.INFO, cid=conn.cid, peer=conn.peer, code=int(err.code),
                   reason=err.text)
        self.sb.protocol_error(conn.cid, err)
        self._try_write(conn)

    async def _read_fd(self, conn: _Conn) -> None:
        """The plain-TCP reader: wait until the socket is readable, then one `os.read` on its descriptor.

        Why not `receive_some`: trio's socket wrapper first tries the read (an EAGAIN system call and a raised
        exception whenever the client has nothing more to say, as after every PING of a lock step) and, after a
        read that succeeds, passes through the scheduler once more (a checkpoint); per small frame that was most
        of an idle server's CPU (`docs/e2e.md`). Waiting first costs nothing when bytes are already queued (the
        poll reports them at once), and it is the checkpoint that lets the other clients run between reads."""
        dec = P.FrameDecoder(self.sb.config.codec)
        fd, size = conn.fd, self.config.read_size
        wait = trio.lowlevel.wait_readable
        while True:
            try:
                await wait(fd)
                data = os.read(fd, size)
            except BlockingIOError:
                continue  # readable was reported but the bytes went elsewhere: wait again
            except (trio.ClosedResourceError, OSError):
                data = b""  # closed under us (a revoked token, shutdown) or reset by the peer
            if not data:
                if dec.mid_frame:
                    logs.event("client vanished mid-frame", logging.INFO, cid=conn.cid, buffered=dec.buffered)
                return
            dec.receive_data(data)
            try:
                while (msgs := dec.next_messages()) is not None:
                    if len(msgs) == 1 and type(msgs[0]) is P.Ping and self._pong_now(conn, msgs[0]):
                        continue
                    await self._feed(conn, msgs)
            except P.ProtocolError as err:
                self._reject(conn, err)
                return
            ob = self.sb.outbox(conn.cid)
            if ob is None or ob.close_after:
                return

    def _pong_now(self, conn: _Conn, ping: P.Ping) -> bool:
        """Answer a frame that is one PING right here, when the core says the PONG overtakes nothing
        (`Switchboard.quick_pong`); False: feed the frame as usual."""
        if conn.busy or conn.closed:
            return False
        pong = self.sb.quick_pong(conn.cid, ping, self.clock())
        if pong is None:
            return False
        if self.pacer is not None:
            self.pacer.woke()  # input all the same: paced like any frame (`_note_news` does it for those)
        head = P.frame_prefix(1, len(pong))
        self.written += 1
        self.frames += 1
        sent = self._writev(conn, head, pong)
        if sent is not None and sent < len(head) + len(pong):
            conn.rest = (head + pong)[sent:]  # the writer task sends the rest
            conn.busy = True
            conn.wake.set()
        return True

    async def _read_tcp(self, conn: _Conn) -> None:
        dec = P.FrameDecoder(self.sb.config.codec)
        stream = conn.stream
        size = self.config.read_size
        while True:
            try:
                data = await stream.receive_some(size)
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                data = b""
            if not data:
                if dec.mid_frame:
                    logs.event("client vanished mid-frame", logging.INFO, cid=conn.cid, buffered=dec.buffered)
                return
            dec.receive_data(data)
            try:
                while (msgs := dec.next_messages()) is not None:
                    await self._feed(conn, msgs)
            except P.ProtocolError as err:
                self._reject(conn, err)
                return
            ob = self.sb.outbox(conn.cid)
            if ob is None or ob.close_after:
                return

    async def _read_ws(self, conn: _Conn) -> None:
        ws = conn.stream
        limits = self.sb.config.codec
        while True:
            try:
                data = await ws.get_message()
            except trio_websocket.ConnectionClosed:
                return
            if not isinstance(data, bytes):
                self._reject(conn, P.ProtocolError(P.ErrorCode.MALFORMED, "send binary WebSocket messages"))
                return
            try:
                await self._feed(conn, P.decode_payload(data, limits))
            except P.ProtocolError as err:
                self._reject(conn, err)
                return
            ob = self.sb.outbox(conn.cid)
            if ob is None or ob.close_after:
                return
