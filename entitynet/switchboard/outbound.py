"""Outbound bookkeeping of the switchboard core: replies and errors, the per-frame reply bound, outbox bounds
and slow consumers.

A mixin of `Switchboard` (entitynet.switchboard.core), split off to keep each module to one job. A frame may
ask for at most `max_replies_per_frame` replies (PONG, QUERY_RESULT, ERROR): its further requests are refused
with one TOO_MANY_REQUESTS error at the end of the frame, so a client that reads promptly is never dropped as a
slow consumer for what one frame asked (the reply bound stays below `max_control`, the outbox bound for a
client that does not read).
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Iterable
from typing import TYPE_CHECKING

from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from entitynet.switchboard.outbox import Outbox

if TYPE_CHECKING:
    from entitynet.switchboard.tables import ClientState

log = logging.getLogger("entitynet.switchboard")


class OutboundMixin:
    """What the core queues for a client besides forwarded states; uses the tables of `Switchboard`."""

    def has_news(self) -> bool:
        """Something was queued for some client since the last `take_dirty` (the shell's flusher waits for it)."""
        return bool(self._dirty)

    def mark_dirty(self, cids: Iterable[int]) -> None:
        """Name these clients in the next `take_dirty` again: the shell's flush held their small frames for the
        next flush (`entitynet.server.flushloop.flush_short`, `hold_below`); what they hold stays queued."""
        dirty = self._dirty
        for cid in cids:
            dirty.add(cid)

    def dirty_count(self) -> int:
        """How many clients have news since the last `take_dirty`: the shell's flusher sizes its wait by it
        (messages queued per waiting client)."""
        return len(self._dirty)

    def quick_pong(self, cid: int, ping: P.Ping, now: float, states_ok: bool = False) -> bytes | None:
        """The encoded PONG for a client frame that is one PING, for the shell to write at once, past the
        outbox; None when the frame must be fed as usual (`receive`): the client is not past its handshake or is
        closing, or something is queued for it (then the usual path writes the PONG and that in one frame, replies
        first). With `states_ok`, coalesced states may be pending (no reply, no close): the shell then writes
        the PONG and those states in one frame, the PONG first, as the usual path would, or feeds the frame as
        usual when it cannot take them all (`Outbox.take_states`). One PING is within any frame's
        reply bound (`max_replies_per_frame` >= 1), so nothing is counted or refused. Why: a lock step's
        barrier PINGs every client once per tick, and through `receive` and the outbox each cost more than
        the write itself."""
        if not self.pong_clear(cid, states_ok):
            return None
        return P.encode_message(P.Pong(ping.client_ms, P.now_ms(max(now, 0.0))))

    def pong_clear(self, cid: int, states_ok: bool = False) -> bool:
        """`quick_pong`'s decision alone: whether a PONG written now, past the outbox, overtakes nothing. Why
        apart: the compiled read path (entitynet.server._hubpass) encodes the PONG itself, in C, and asks the
        core only this; the PONG's bytes are the same (tests compare them)."""
        c = self.clients.get(cid)
        if c is None or not c.ready or c.closing or c.outbox.close_after:
            return False
        return not (c.outbox.has_control if states_ok else len(c.outbox))

    def written_out(self, cid: int) -> None:
        """The shell has just written everything queued for `cid` itself (a reader answering its client's PING
        at once): it has no news left, so the flusher is not woken for it. A lock step's PINGs otherwise each
        cost a flusher wake-up that finds nothing to write."""
        c = self.clients.get(cid)
        if c is not None and not len(c.outbox) and not c.outbox.close_after:
            self._dirty.discard(cid)

    def take_dirty(self, check: bool = True) -> Collection[int]:
        """Clients with something new to write since the last call: their ids (a Python set, or on the compiled
        path a list in ascending order, taken from the `CidMarks` in place). With `check`, also enforces the outbox
        bounds (a shell that drains each outbox right away calls `check_outbox` then instead: one pass)."""
        dirty = self._dirty
        if type(dirty) is set:
            self._dirty = set()
        else:
            dirty = dirty.take()  # visits only the marked words and clears them: nothing is allocated
        self.replies_waiting = False
        if not check:
            return dirty
        # ascending on both paths: dropping one slow consumer changes what the next one's entities leave, so
        # the pure path's set order would make its LEAVEs and counters differ from the compiled path's
        for cid in dirty if type(dirty) is list else sorted(dirty):
            c = self.clients.get(cid)
            if c is not None and c.outbox.over_bounds:
                self.slow_consumer(cid, "outbound queue limit")
        return dirty

    def check_outbox(self, cid: int, ob: Outbox) -> bool:
        """False (and the client is being dropped as a slow consumer) when its outbox is beyond its bounds."""
        if ob.over_bounds:
            self.slow_consumer(cid, "outbound queue limit")
            return False
        return True

    def slow_consumer(self, cid: int, why: str) -> None:
        """Drop what is pending for a client that does not keep up, tell it, and close it."""
        c = self.clients.get(cid)
        if c is None or c.closing:
            return
        c.outbox.discard()
        self.stats["slow_consumers"] += 1
        self._error(c, ErrorCode.SLOW_CONSUMER, f"too far behind ({why}); disconnecting")

    def _end_frame(self, c: ClientState) -> None:
        if c.refused and not c.closing:
            cap = self.config.max_replies_per_frame
            self.errors[int(ErrorCode.TOO_MANY_REQUESTS)] += 1
            c.outbox.put_control(P.encode_message(P.Error(
                int(ErrorCode.TOO_MANY_REQUESTS),
                f"{c.refused} requests of one frame refused: at most {cap} replies (PONG, QUERY_RESULT, ERROR) "
                "per frame",
            )))
            self._dirty.add(c.cid)
        c.replies = c.refused = 0

    def _reply_msg(self, c: ClientState, msg: P.Message) -> None:
        self._reply(c, P.encode_message(msg))

    def _reply(self, c: ClientState, encoded: bytes) -> None:
        """Queue a reply, unless this frame already asked for `max_replies_per_frame` (then count it refused:
        one TOO_MANY_REQUESTS at the end of the frame says so, instead of the outbox overflowing)."""
        if c.replies >= self.config.max_replies_per_frame:
            c.refused += 1
            return
        c.replies += 1
        c.outbox.put_control(encoded)
        self._dirty.add(c.cid)

    def _error(self, c: ClientState, code: ErrorCode, text: str) -> None:
        if code in P.FATAL_ERRORS:
            self.errors[int(code)] += 1
            if c.closing:
                return
            c.outbox.put_last_word(P.encode_message(P.Error(int(code), text)))  # beyond the bound: it must go
            c.closing = True
            self._detach(c)
            log.info("closing client", extra={"cid": c.cid, "code": int(code), "reason": text})
        elif c.replies >= self.config.max_replies_per_frame:
            c.refused += 1
            return
        else:
            self.errors[int(code)] += 1
            c.replies += 1
            c.outbox.put_control(P.encode_message(P.Error(int(code), text)))
        self._dirty.add(c.cid)
