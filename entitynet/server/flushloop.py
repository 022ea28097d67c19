"""The flush's per-connection loop: every dirty connection's coalesced states as one frame, one `writev` each.

Why a module of its own: under load the flush is where the server's time goes (profiled at the standard switch
load: about 60 % of the server's samples, two thirds of them the `writev` system calls and one third Python
around them, about 5 µs per frame). The loop is written once here in plain Python, the reference, and once
compiled (`_flushloop.pyx`, built by pip with Cython when a compiler is there), which does the same per
connection without the interpreter: the prefix is packed and the system call made in C. `use_compiled` picks
one for the process (ENTITYNET_PURE_PYTHON=1 forces the reference); tests run both and compare the bytes.

Only the common case is handled here: a plain TCP socket whose outbox holds only coalesced states that fit one
frame (`Outbox.take_states`). Everything else (replies, a close, a backlog over one frame, WebSocket and TLS,
a connection whose writer task is busy) is handed back for the writer's long path, unchanged.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass
from types import ModuleType, SimpleNamespace
from typing import Any

from entitynet.protocol import frame_prefix

LATENCY_EVERY = 64  # one queue-latency sample per this many frames written (Histogram.observe costs a write's;
# at 16 the histogram was 1.7 % of the server's CPU at the standard load)


@dataclass
class FlushConn:
    """The fields of the server's connection record (`entitynet.server.app._Conn`) that the flush loop reads
    and writes: what a benchmark or a test drives the loop with, without a server around it."""

    cid: int
    outbox: Any
    fd: int | None
    busy: bool = False
    closed: bool = False
    dirty_since: float | None = None
    rest: bytes | None = None


def flush_short_py(dirty: Iterable[int], conns: dict, now: float, max_messages: int, sure_fit: int, max_body: int,
                   lat_n: int, hold_below: int = 0) -> tuple[int, int, int, list[float], list, list, list, list]:
    """Write one frame to every connection in `dirty` (client ids) that takes the short path.

    Per connection: none (gone) is skipped; `dirty_since` is set to `now` when unset; a busy or closed one is
    skipped (its writer takes the news when it is done); one without a plain socket goes to `slow`. A small
    frame waits once: a connection this flush is the first to find with news (`dirty_since` was unset) whose
    outbox holds only states, fewer than `hold_below` (`Outbox.holds_few`), is not written but goes to `held`
    (its id; the caller marks it dirty again), so that the next flush writes its news with whatever arrived
    meanwhile (a frame costs a `writev` whatever it carries; held once, the next flush writes it whatever its
    size, so the added latency is bounded by one flush interval). One whose outbox `take_states` refuses goes to
    `slow`. The frame (length prefix and array header, then the joined states)
    is written with one `writev`: written whole, the connection's latency is sampled every `LATENCY_EVERY`
    frames and `dirty_since` cleared; partly written, the rest goes to `conn.rest`, `conn.busy` is set and the
    connection goes to `blocked` (its writer finishes it); a failed write puts it in `failed` (peer gone).

    Returns (messages, frames, lat_n, latency samples in s, slow, blocked, failed, held)."""
    n_msgs = n_frames = 0
    samples: list[float] = []
    slow: list = []
    blocked: list = []
    failed: list = []
    held: list = []
    writev = os.writev
    for cid in dirty:
        conn = conns.get(cid)
        if conn is None:
            continue
        fresh = conn.dirty_since is None
        if fresh:
            conn.dirty_since = now
        if conn.busy or conn.closed:
            continue
        fd = conn.fd
        if fd is None:
            slow.append(conn)
            continue
        if fresh and hold_below > 1 and conn.outbox.holds_few(hold_below):
            held.append(cid)
            continue
        taken = conn.outbox.take_states(max_messages, sure_fit, max_body)
        if taken is None:
            slow.append(conn)
            continue
        n, body = taken
        head = frame_prefix(n, len(body))
        n_msgs += n
        n_frames += 1
        try:
            sent = writev(fd, (head, body))
        except BlockingIOError:
            sent = 0
        except OSError:
            failed.append(conn)
            continue
        if sent == len(head) + len(body):
            lat_n += 1
            if lat_n % LATENCY_EVERY == 0:
                samples.append(max(0.0, time.monotonic() - conn.dirty_since))
            conn.dirty_since = None
        else:
            conn.rest = (head + body)[sent:]
            conn.busy = True
            blocked.append(conn)
    return n_msgs, n_frames, lat_n, samples, slow, blocked, failed, held


PURE: Any = SimpleNamespace(flush_short=flush_short_py)
COMPILED: ModuleType | None
try:
    from entitynet.server import _flushloop as COMPILED  # type: ignore[attr-defined, no-redef]
except ImportError:  # not built (no compiler at install time): the reference path
    COMPILED = None
_impl: Any = PURE


def use_compiled(flag: bool = True) -> bool:
    """Select the flush loop for this process: the compiled one when `flag` and it was built, else the
    pure-Python reference. Returns whether the compiled one is now in use."""
    global _impl
    _impl = COMPILED if flag and COMPILED is not None else PURE
    return _impl is COMPILED


def compiled_in_use() -> bool:
    """Whether the compiled flush loop is in use (the bench reports it)."""
    return COMPILED is not None and _impl is COMPILED


def flush_short(dirty: Iterable[int], conns: dict, now: float, max_messages: int, sure_fit: int, max_body: int,
                lat_n: int, hold_below: int = 0) -> tuple[int, int, int, list[float], list, list, list, list]:
    """`flush_short_py` or its compiled twin, whichever `use_compiled` selected."""
    return _impl.flush_short(dirty, conns, now, max_messages, sure_fit, max_body, lat_n, hold_below)


use_compiled(not os.environ.get("ENTITYNET_PURE_PYTHON"))
