"""The read hub's per-read path for a plain-TCP connection: one read, and a read that is one whole PING frame
answered right there; written once in plain Python (the reference) and once compiled (`_hubpass.pyx`).

Why a module of its own: in `bench e2e`'s lock step every connection sends one PING per tick, and for each the
server ran this path in the interpreter: `os.read` into a new bytes object, the PING recogniser
(entitynet.server.pingframe), the PONG's frame prefix and the `os.writev` call with its exception handling. The
compiled twin reads into one reusable buffer, recognises the PING and packs the prefix in C and calls
`read(2)`/`writev(2)` directly (the sockets are non-blocking: the GIL is held, the calls return at once); a read
that is not a lone PING becomes a bytes object only then and goes the server's general way (`_hub_bytes`).
Whether the PONG may go at once stays the core's decision (`Switchboard.pong_clear`, which `quick_pong` asks
too); the reference takes the PONG's bytes from `quick_pong`, the compiled twin encodes the same bytes in C (no
`Ping`, `Pong` or bytes object per PING: that was about half of what the core's part cost). `use_compiled`
picks one for the process (ENTITYNET_PURE_PYTHON=1 forces the reference); tests run both on the same bytes and
compare what they write and what they leave behind.

The server side these functions use (entitynet.server.reading, `ReadingMixin`): `config.read_size`, `sb`,
`clock()`, `pacer`, the `written`/`frames` counters, `_hub_eof(conn)`, `_hub_bytes(conn, data)` and
`_pong_with_states(conn, pong)`; of the connection record: `fd`, `decoder`, `busy`, `closed`, `cid`, `outbox`,
`scope`, `rest`, `wake`.
"""

from __future__ import annotations

import os
from types import ModuleType, SimpleNamespace
from typing import Any

from entitynet import protocol as P
from entitynet.server.pingframe import lone_ping_ms


def hub_ready_py(server: Any, conn: Any) -> None:
    """One `os.read` of a readable connection: end of stream to `server._hub_eof`, a lone PING answered now
    (`pong_now_py`), anything else to `server._hub_bytes` (the deframer and the core)."""
    try:
        data = os.read(conn.fd, server.config.read_size)
    except BlockingIOError:
        return  # readable was reported but the bytes went elsewhere: the next poll tells
    except OSError:
        data = b""  # closed under us (a revoked token, shutdown) or reset by the peer
    if not data:
        server._hub_eof(conn)
        return
    if not conn.decoder.mid_frame and (ms := lone_ping_ms(data)) is not None and pong_now_py(server, conn, ms):
        return  # the lock step's PING: answered without the deframer (entitynet.server.pingframe)
    server._hub_bytes(conn, data)


def pong_now_py(server: Any, conn: Any, client_ms: int) -> bool:
    """Answer a plain-TCP frame that is one PING (`client_ms`) at once when the core says the PONG overtakes
    nothing (`Switchboard.quick_pong`); False: feed the frame as usual. States waiting for the flush go in the
    same frame, after the PONG (`server._pong_with_states`)."""
    if conn.busy or conn.closed:
        return False
    pong = server.sb.quick_pong(conn.cid, P.Ping(client_ms), server.clock(), states_ok=True)
    if pong is None:
        return False
    if server.pacer is not None:
        server.pacer.woke()  # input all the same: paced like any frame (`_note_news` does it for those)
    if len(conn.outbox):
        return server._pong_with_states(conn, pong)
    head = P.frame_prefix(1, len(pong))
    server.written += 1
    server.frames += 1
    try:
        sent: int | None = os.writev(conn.fd, (head, pong))
    except BlockingIOError:
        sent = 0
    except OSError:
        sent = None
        if conn.scope is not None:
            conn.scope.cancel()  # peer gone: the handler closes and disconnects
    if sent is not None and sent < len(head) + len(pong):
        conn.rest = (head + pong)[sent:]  # the writer task sends the rest
        conn.busy = True
        conn.wake.set()
    return True


PURE: Any = SimpleNamespace(hub_ready=hub_ready_py, pong_now=pong_now_py, lone_ping_ms=lone_ping_ms)
COMPILED: ModuleType | None
try:
    from entitynet.server import _hubpass as COMPILED  # type: ignore[attr-defined, no-redef]
except ImportError:  # not built (no compiler at install time): the reference path
    COMPILED = None
_impl: Any = PURE


def use_compiled(flag: bool = True) -> bool:
    """Select the read path for this process: the compiled one when `flag` and it was built, else the
    pure-Python reference. Returns whether the compiled one is now in use. (A server binds the selection
    when it starts: `hub_ready_for`.)"""
    global _impl
    _impl = COMPILED if flag and COMPILED is not None else PURE
    return _impl is COMPILED


def compiled_in_use() -> bool:
    """Whether the compiled read path is in use (the bench reports it)."""
    return COMPILED is not None and _impl is COMPILED


def impl() -> Any:
    """The selected implementation (`hub_ready`, `pong_now`, `lone_ping_ms`)."""
    return _impl


use_compiled(not os.environ.get("ENTITYNET_PURE_PYTHON"))
