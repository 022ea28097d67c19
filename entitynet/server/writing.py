"""The server's writing path: draining outboxes into frames, the synchronous first write, the writer tasks, the
flusher.

A mixin of `Server` (entitynet.server.app), split off to keep each module to one job. Why it looks like this:
the core coalesces into each client's outbox, and every `flush_interval` the flusher drains each client with
news into one frame and writes it at once, synchronously, on the non-blocking socket (no task switch: that is
what makes a thousand viewers cheap). Whatever the kernel does not take goes to that connection's writer task.
Every frame stays within the codec's `max_frame` (the limit announced in WELCOME; a client's decoder refuses
anything larger): a backlog larger than one frame leaves as several. The writer reports progress as it goes,
so that the stall timer counts only the time a client does not read.
"""

from __future__ import annotations

import math
import os
import time
from typing import TYPE_CHECKING

import trio
import trio_websocket
from trio.testing import wait_all_tasks_blocked

from entitynet import protocol as P
from entitynet.server.flushloop import LATENCY_EVERY, flush_short

if TYPE_CHECKING:
    from entitynet.server.app import _Conn


IDLE_BACKSTOP_S = 1.0  # an idle flusher looks anyway after this long


class WritingMixin:
    """Outbound half of `Server`; uses its `sb`, `config`, `metrics`, `conns` and counters."""


    def _try_write(self, conn: _Conn) -> None:
        """Drain the outbox into one frame and write what the socket takes now; the writer task gets the rest."""
        if conn.busy or conn.closed:
            return
        ob = conn.outbox
        if conn.fd is not None:
            # the common case, kept short (it runs once per frame): only coalesced states, a plain socket
            taken = ob.take_states(self._fast_batch, self._sure_fit, self._max_body)
            if taken is not None:
                self._write_states(conn, *taken)
                return
        if ob.over_bounds:
            self.sb.check_outbox(conn.cid, ob)  # drops it: SLOW_CONSUMER is now the only thing queued
        self._write_msgs(conn, ob.drain(self.config.max_batch, self._max_body))  # one frame; the rest waits

    def _write_states(self, conn: _Conn, n: int, body: bytes) -> None:
        """The short path of `_try_write`: `n` states joined in `body` (known to fit one frame) to a plain
        socket."""
        head = P.frame_prefix(n, len(body))
        self.written += n
        self.frames += 1
        sent = self._writev(conn, head, body)
        if sent is None:
            return
        if sent == len(head) + len(body):
            if conn.dirty_since is not None:
                self._written(conn)
            return
        conn.rest = (head + body)[sent:]
        conn.busy = True
        conn.wake.set()

    def _write_msgs(self, conn: _Conn, msgs: list[bytes]) -> None:
        """One frame of drained messages: written now as far as the socket takes it, the rest by the writer."""
        ob = conn.outbox
        if not msgs:
            if ob.close_after:
                conn.busy = True
                conn.wake.set()  # the writer closes the connection
            return
        # the messages are copied once (one join); array header and length prefix go in front via writev
        body = b"".join(msgs)
        head = P.array_header(len(msgs))
        self.written += len(msgs)  # pushed to the Prometheus counters by the housekeeping task
        self.frames += 1
        if conn.fd is None:  # WebSocket (one message per payload) or TLS (framed): the writer task sends
            data = head + body if conn.kind == "ws" else P.frame_head(len(head) + len(body)) + head + body
        else:
            head = P.frame_head(len(head) + len(body)) + head
            n = self._writev(conn, head, body)
            if n is None:
                return
            if n == len(head) + len(body):
                self._written(conn)
                if len(ob) or ob.close_after:
                    conn.busy = True
                    conn.wake.set()
                return
            data = (head + body)[n:]
        conn.rest = data
        conn.busy = True
        conn.wake.set()

    @staticmethod
    def _writev(conn: _Conn, head: bytes, body: bytes) -> int | None:
        """Write what the non-blocking socket takes now: bytes sent, or None when the peer is gone."""
        try:
            return os.writev(conn.fd, (head, body))
        except BlockingIOError:
            return 0
        except OSError:
            if conn.scope is not None:
                conn.scope.cancel()  # peer gone: the handler closes and disconnects
            return None

    def _written(self, conn: _Conn) -> None:
        if conn.dirty_since is not None:
            self._lat_n += 1
            if self._lat_n % LATENCY_EVERY == 0:  # a sample: Histogram.observe costs more than the write itself
                self.metrics.latency.observe(max(0.0, time.monotonic() - conn.dirty_since))
            conn.dirty_since = None

    async def _writer(self, conn: _Conn) -> None:
        """Finishes the writes `_try_write` could not, and closes the connection when the core says so."""
        while True:
            await conn.wake.wait()
            conn.wake = trio.Event()
            rest, conn.rest = conn.rest, None
            if rest:
                conn.writing = True
                self._watch_stalls()
                conn.stalled = 0.0
                try:
                    if conn.kind == "ws":
                        await conn.stream.send_message(rest)
                    elif conn.fd is not None:
                        await self._send_observed(conn, rest)
                    else:
                        await conn.stream.send_all(rest)
                except (trio.BrokenResourceError, trio.ClosedResourceError, OSError,
                        trio_websocket.ConnectionClosed):
                    conn.scope.cancel()
                    return
                conn.writing = False
                self._written(conn)
            conn.busy = False
            ob = self.sb.outbox(conn.cid)
            if ob is None:
                return
            if len(ob):
                self._try_write(conn)
            elif ob.close_after:
                conn.scope.cancel()
                return

    @staticmethod
    async def _send_observed(conn: _Conn, data: bytes) -> None:
        """send_all on the plain socket, resetting the connection's stall whenever the kernel takes bytes: only
        time without progress counts against the client."""
        view = memoryview(data)
        sock = conn.stream.socket
        while view:
            try:
                n = os.write(conn.fd, view)
            except BlockingIOError:
                n = 0
            if n:
                view = view[n:]
                conn.stalled = 0.0
            else:
                await trio.lowlevel.wait_writable(sock)
        await trio.lowlevel.checkpoint()

    def _wake_dirty(self) -> None:
        """Flush: every connection with news gets one frame now (`flushloop.flush_short`, compiled where built);
        those it cannot serve (replies, a close, more than one frame, WebSocket or TLS) take `_try_write`."""
        stats = self.sb.stats
        self._queued_mark = stats["deliveries"] + stats["leaves"]
        n_msgs, n_frames, self._lat_n, samples, slow, blocked, failed, held = flush_short(
            self.sb.take_dirty(check=False), self.conns, time.monotonic(), self._fast_batch, self._sure_fit,
            self._max_body, self._lat_n, self.config.flush_min_frame)
        if held:  # small frames wait for the next flush (once): it comes within the latency budget
            self.sb.mark_dirty(held)
            if not self._news.is_set():
                self._news_at = trio.current_time()
                self._news.set()
        self.written += n_msgs
        self.frames += n_frames
        for s in samples:
            self.metrics.latency.observe(s)
        for conn in blocked:
            conn.wake.set()  # the writer task sends `conn.rest`
        for conn in failed:
            if conn.scope is not None:
                conn.scope.cancel()  # peer gone: the handler closes and disconnects
        for conn in slow:
            self._try_write(conn)

    def _note_news(self) -> None:
        """The core may have queued something for a client: wake the flusher if so (and, while it waits out the
        latency budget, once the queue is full enough to flush now). Called wherever the core is fed outside
        `_wake_dirty` (each slice of a client frame, NATS messages, the cluster's and the server's timers); a
        path that forgot to call it costs at most the flusher's `IDLE_BACKSTOP_S`."""
        if self.pacer is not None:
            self.pacer.woke()
        if not self._news.is_set():
            if self.sb.has_news():
                self._news_at = trio.current_time()
                self._news.set()
        elif self._filled is not None and self._queue_full():
            self._filled.set()

    def _queue_full(self) -> bool:
        """Whether what is queued is worth a flush before the latency budget runs out: on average at least
        `flush_fill` messages for each connection with news (a frame costs a wake-up of its reader and a
        `writev` whatever it carries, so under load frames fill at once and nothing waits); or at once when a
        reply the reader did not write is queued (`Switchboard.replies_waiting`: a client waits for it)."""
        if self.sb.replies_waiting:
            return True
        stats = self.sb.stats
        queued = stats["deliveries"] + stats["leaves"] - self._queued_mark
        return queued >= self.config.flush_fill * self.sb.dirty_count()

    async def _flusher(self) -> None:
        """Flush adaptively, sized by what is queued and bounded by the latency budget (`latency_budget`, B).

        With news queued: while less than `flush_fill` messages per connection with news wait (light load),
        wait up to B from the first news for more to share the flush, so that one wake-up of the flusher and one
        `writev` per connection carry many deliveries instead of one each (a server at 1/K of the load then pays
        about what a full one pays per delivery, not K times it). Once that much is queued, or B has passed,
        flush as soon as the loop has nothing else to do (every reader has drained its pending input: as Redis
        writes after each pass of its event loop), so that news goes out while the process is awake instead of
        at a timer tick; but after a flush that took W seconds of CPU, not before W has passed since it ended
        (nor `flush_min_interval`), and while the loop stays busy, at the latest `flush_interval` after the
        previous flush began (or W after it ended, if later). So the flusher takes at most about half of the
        time: under load reading keeps the other half and the batches grow (writes cost per frame, for the
        server and its readers alike, not per message) instead of the flusher eating the CPU. With nothing
        queued it sleeps until `_note_news` (an idle server, or an idle shard of a cluster, then costs no
        wake-ups; `IDLE_BACKSTOP_S` only bounds the harm of a feeding path that forgot to call it).

        The bound on added latency: news waits at most max(B, `flush_interval`, W) for its flush to begin, plus
        the wait for the loop to be idle; B = 0 flushes as soon as the loop is idle."""
        bound = self.config.flush_interval
        budget = self.config.latency_budget
        gap = min(self.config.flush_min_interval, bound)
        last_start = last_end = -math.inf
        cost = 0.0
        while True:
            if not self._news.is_set():
                with trio.move_on_after(IDLE_BACKSTOP_S):
                    await self._news.wait()
                if not self.sb.has_news():
                    continue
            if budget > 0.0 and not self._queue_full():
                self._filled = trio.Event()
                try:
                    with trio.move_on_at(self._news_at + budget):
                        await self._filled.wait()
                finally:
                    self._filled = None
            earliest = last_end + max(gap, cost)
            if trio.current_time() < earliest:
                await trio.sleep_until(earliest)
            latest = max(last_start + bound, last_end + cost)
            if trio.current_time() < latest:
                with trio.move_on_at(latest):
                    await wait_all_tasks_blocked()
            self._news = trio.Event()
            last_start = trio.current_time()
            cpu = time.thread_time()
            self._wake_dirty()
            last_end = trio.current_time()
            cost = time.thread_time() - cpu  # CPU, not wall time: time preempted by other processes is not ours
