"""The server's reading path: a connection's bytes into frames, frames fed to the core in slices, and the
frames that are one PING answered at once.

A mixin of `Server` (entitynet.server.app), split off to keep each module to one job. Reading: bytes ->
FrameDecoder (TCP) or one WebSocket message -> decode_payload -> `Switchboard.receive`. A decode error queues the
numbered ERROR and closes that connection only. A frame is fed to the core in slices (a SUBSCRIBE or QUERY, whose
cost grows with the entities in its cells, ends a slice), and the other clients are served between slices once
they add up to `FEED_YIELD_S` of work, so one client's big frame never keeps the others waiting for long.
Plain-TCP connections are read by one task for all (the read hub, entitynet.server.readhub) as long as their
frames need no await, and by their own task while one does; TLS and WebSocket by their own tasks.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import trio
import trio_websocket

from entitynet import protocol as P
from entitynet.server import hubpass, logs

if TYPE_CHECKING:
    from entitynet.server.app import _Conn

#: a client frame fed in slices yields to the others once its slices since the last yield took this long: a
#: checkpoint is a pass through trio's scheduler (tens of microseconds), more than a small SUBSCRIBE costs, so
#: a frame of a few cheap slices (a viewer's SUBSCRIBE difference and its PING) goes through without one
FEED_YIELD_S = 0.0005


def _cheap_rest(msgs: list[P.Message], start: int, step: int) -> bool:
    """Whether what is left of a frame from `start` on is at most one slice of PINGs: answering them costs less
    than the checkpoint and the hand-over to the connection's task a yield takes (a viewer's SUBSCRIBE
    difference and its barrier PING, `bench e2e`), so the frame is finished without one."""
    return len(msgs) - start <= step and all(type(m) is P.Ping for m in msgs[start:])


class ReadingMixin:
    """Inbound half of `Server`; uses its `sb`, `config`, `tokens`, `metrics`, `clock` and the writing half."""

    async def _feed(self, conn: _Conn, msgs: list[P.Message], start: int = 0) -> None:
        """Feed one frame (from message `start` on) to the core in slices, serving the other clients between
        slices once they took `FEED_YIELD_S` (`_feed_slices`).
        A HELLO whose token the core will check is looked up first, off the loop (entitynet.server.tokens), and
        the answer handed over for the first slice, which the core handles without a task switch."""
        answer = None
        if start == 0 and self._asks_token(conn, msgs):
            answer = (msgs[0].token, await self.tokens.lookup(msgs[0].token))
            if self.sb.outbox(conn.cid) is None:
                return  # it went away (or its handshake timed out) while the store was read
        while (start := self._feed_slices(conn, msgs, start, answer)) is not None:
            await trio.lowlevel.checkpoint()  # the others' frames and the flusher run here
            answer = None

    def _asks_token(self, conn: _Conn, msgs: list[P.Message]) -> bool:
        """Whether this frame opens with a HELLO whose token must be looked up in the store first (an await)."""
        return (self.tokens is not None and bool(msgs) and type(msgs[0]) is P.Hello
                and self.sb.asks_token(conn.cid, msgs[0], self.clock()))

    def _feed_slices(self, conn: _Conn, msgs: list[P.Message], start: int,
                     answer: tuple[str, object] | None = None) -> int | None:
        """Feed slices of one frame from message `start` on, synchronously: a slice ends after `feed_slice`
        messages or after a SUBSCRIBE or QUERY (their work grows with the entities in the cells). Returns None
        when the frame is done (or the connection is closing), else where to go on once the others were served:
        the slices since `start` took `FEED_YIELD_S`. `answer` is a looked-up token for the first slice.

        A frame that ends with its only PING (a lock step's SUBSCRIBE difference or PUBLISHes and their
        barrier PING) is fed without it, and the PING is answered like a frame of its own (`_pong_now`: the
        PONG and the states waiting, in one frame, past the outbox), or fed as one when the core says the PONG
        must queue (`_quick_tail` says why the replies are the same either way)."""
        step = self.config.feed_slice
        n = len(msgs)
        last = n - 1 if self._quick_tail(conn, msgs) else n
        began = time.perf_counter()
        while True:
            while start < last:
                end = start
                limit = min(last, start + step)
                while end < limit:
                    t = type(msgs[end])
                    end += 1
                    if t is P.Subscribe or t is P.Query:
                        break
                part = msgs[start:end] if start or end < n else msgs
                # answers wait for the trailing PING's frame where the whole frame's slice would have held it
                joined = end == last < n and end - start < step and t is not P.Subscribe and t is not P.Query
                if not self._feed_part(conn, part, end >= last, answer, write=not joined):
                    self._note_news()
                    return None  # the connection is closing (or gone)
                answer = None
                start = end
                if start < last and time.perf_counter() - began >= FEED_YIELD_S and not _cheap_rest(msgs, start, step):
                    self._note_news()
                    return start
            if last == n or self._pong_now(conn, msgs[last]):
                break
            last = n  # the PONG must queue behind something: the PING fed as a frame of its own
        # the flusher is told once the frame's synchronous run is done, not after each slice: nothing else runs
        # in between, and a frame's last slice often writes what its first queued (a SUBSCRIBE's states go out
        # with the PONG of the PING after it), which would have cost the flusher a wake-up that finds nothing
        self._note_news()
        return None

    def _feed_part(self, conn: _Conn, part: list[P.Message], frame_end: bool,
                   answer: tuple[str, object] | None, write: bool = True) -> bool:
        """One slice to the core, and its answers (WELCOME, PONG, ERROR) written now, not at the next flush
        (with `write`; else they wait for the trailing PING's frame, which then goes the core's way with them);
        False when the connection is closing or gone (a closing one's last words are written at once)."""
        sb = self.sb
        before = sb.stats["updates_in"]
        if answer is not None:
            with self.tokens.answering(*answer):
                sb.receive(conn.cid, part, self.clock(), frame_end=frame_end)
        else:
            sb.receive(conn.cid, part, self.clock(), frame_end=frame_end)
        if sb.stats["updates_in"] != before:  # a PING or SUBSCRIBE frame costs no Prometheus call
            self.metrics.updates_in.inc(sb.stats["updates_in"] - before)
        self._rearm()
        ob = sb.outbox(conn.cid)
        if ob is not None and (ob.close_after or (write and ob.has_control)):
            self._try_write(conn)
            if not conn.busy:
                sb.written_out(conn.cid)  # all of it went: no flusher wake-up for this client
        return ob is not None and not ob.close_after

    def _quick_tail(self, conn: _Conn, msgs: list[P.Message]) -> bool:
        """Whether the frame's last message, a PING, may be answered as a frame of its own after the rest
        (plain TCP only: `_pong_now` writes to the socket). The replies are the same as the core's for the
        whole frame: the PING is the frame's only request (no other PING or QUERY), and the frame has at most
        `max_replies_per_frame` messages, each of which asks for at most one reply (an ERROR), so the PING is
        within the frame's reply bound either way; the rest ends the core's frame first, which then has
        nothing refused to report."""
        n = len(msgs)
        if conn.fd is None or n < 2 or type(msgs[-1]) is not P.Ping or n > self.sb.config.max_replies_per_frame:
            return False
        for m in msgs[:-1]:
            t = type(m)
            if t is P.Ping or t is P.Query:
                return False
        return True

    def _reject(self, conn: _Conn, err: P.ProtocolError) -> None:
        logs.event("protocol error", logging.INFO, cid=conn.cid, peer=conn.peer, code=int(err.code),
                   reason=err.text)
        self.sb.protocol_error(conn.cid, err)
        self._try_write(conn)

    def _next_to_feed(self, conn: _Conn) -> list[P.Message] | None:
        """The connection's next whole frame that must be fed to the core, or None when no whole frame is
        buffered; frames that are one PING are answered on the way (`_pong_now`). Raises ProtocolError."""
        dec = conn.decoder
        while (msgs := dec.next_messages()) is not None:
            if len(msgs) != 1 or type(msgs[0]) is not P.Ping or not self._pong_now(conn, msgs[0]):
                return msgs
        return None

    def _closing(self, conn: _Conn) -> bool:
        ob = self.sb.outbox(conn.cid)
        return ob is None or ob.close_after

    def _hub_reader(self) -> Callable[[_Conn], None]:
        """The read hub's call for a readable plain-TCP connection (entitynet.server.readhub): the selected
        `hubpass.hub_ready` bound to this server (one read; a lone PING answered at once, the rest to
        `_hub_bytes`)."""
        return functools.partial(hubpass.impl().hub_ready, self)

    def _hub_eof(self, conn: _Conn) -> None:
        """The read hub's connection ended (or its read failed): its task takes over and ends it."""
        if conn.decoder.mid_frame:
            logs.event("client vanished mid-frame", logging.INFO, cid=conn.cid, buffered=conn.decoder.buffered)
        self._hand_off(conn, None)

    def _hub_bytes(self, conn: _Conn, data: bytes) -> None:
        """The read hub's bytes that are not one lone PING (entitynet.server.hubpass reads them): the frames
        fed to the core right here, synchronously. The connection goes to its own task (`_read_plain`) when a
        frame must await there (a token to look up, a big frame that yields between slices: `conn.pending` says
        where to go on) or when it is closing (`conn.pending` None)."""
        conn.decoder.receive_data(data)
        try:
            while (msgs := self._next_to_feed(conn)) is not None:
                start = 0 if self._asks_token(conn, msgs) else self._feed_slices(conn, msgs, 0)
                if start is not None:
                    self._hand_off(conn, (msgs, start))
                    return
                if self._closing(conn):
                    self._hand_off(conn, None)
                    return
        except P.ProtocolError as err:
            self._reject(conn, err)
            self._hand_off(conn, None)
        except Exception as exc:  # a bug: raised in the connection's own task, as a reader task would have
            self._hand_off(conn, exc)

    def _hand_off(self, conn: _Conn, work: tuple[list[P.Message], int] | BaseException | None) -> None:
        """Take the connection out of the hub and wake its task with `work`."""
        self.hub.discard(conn)
        conn.pending = work
        if conn.handoff is not None:
            conn.handoff.set()

    async def _read_plain(self, conn: _Conn) -> None:
        """The plain-TCP reader task: the connection is served by the read hub (`_hub_reader`) while its frames
        go through without an await; this task takes over when one must await, catches up on what the
        decoder holds (in order: the hub does not read the socket meanwhile), and hands it back.

        Why not a task reading its own socket: per small frame that costs a pass through trio's scheduler and
        an `epoll_ctl` (trio's interest is one-shot), and in a lock step every client sends one at once; the
        hub serves all ready sockets in one wake-up (entitynet.server.readhub, docs/switch.md)."""
        conn.decoder = P.FrameDecoder(self.sb.config.codec)
        try:
            while True:
                conn.handoff = trio.Event()
                self.hub.add(conn)
                await conn.handoff.wait()
                work, conn.pending = conn.pending, None
                if work is None:
                    return
                if isinstance(work, BaseException):
                    raise work
                try:
                    await self._feed(conn, *work)
                    while not self._closing(conn) and (msgs := self._next_to_feed(conn)) is not None:
                        await self._feed(conn, msgs)
                except P.ProtocolError as err:
                    self._reject(conn, err)
                    return
                if self._closing(conn):
                    return
        finally:
            self.hub.discard(conn)

    def _pong_now(self, conn: _Conn, ping: P.Ping) -> bool:
        """Answer a plain-TCP frame that is one PING right here, when the core says the PONG overtakes nothing
        (`Switchboard.quick_pong`); False: feed the frame as usual. States waiting for the flush go in the same
        frame, after the PONG (as the usual path orders them): one `writev` instead of the flusher's and the
        PONG's (a lock step's viewers PING right after the tick's publishes). The selected implementation of
        entitynet.server.hubpass (compiled or the reference)."""
        return bool(hubpass.impl().pong_now(self, conn, ping.client_ms))

    def _pong_with_states(self, conn: _Conn, pong: bytes) -> bool:
        """`_pong_now`'s frame when coalesced states wait: the PONG and those states in one frame, or False
        (nothing taken: the frame is fed as usual) when they are more than one frame's worth."""
        taken = conn.outbox.take_states(self._fast_batch - 1, self._sure_fit - 1, self._max_body - len(pong))
        if taken is None:
            return False
        self._write_states(conn, taken[0] + 1, pong + taken[1])
        self.sb.written_out(conn.cid)  # no flusher wake-up for what went here
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
