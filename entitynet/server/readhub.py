"""One reader for every plain-TCP connection: a level-triggered epoll set that a single trio task waits on.

Why: with a task per connection, every small frame (a lock step's PING above all) costs a pass of that task
through trio's scheduler and, because trio registers a one-shot interest per wait, an `epoll_ctl` to wait
again; when many clients speak at once (`bench e2e`'s barrier PINGs every connection per tick) that was most
of what an idle server spent (docs/switch.md, "The reading path"). Here each connection is registered once, in
our own `select.epoll` set, level-triggered (no re-arm per read); one task waits until that set is readable and
then serves every ready connection in one pass (`ready(conn)`: one read, its frames fed to the core
synchronously). A connection whose frame needs to await (a token looked up off the loop, a big frame that must
yield between slices) or that ended is taken out of the set and handed to its own reader task, which
re-registers it once it has caught up: frames of one connection are still handled in order, by one of the two.

The hub knows nothing of frames or the core: `ready` is the server's (entitynet.server.hubpass, bound by
entitynet.server.reading). TLS and WebSocket connections keep their own reader tasks and streams.

A registered connection's socket is closed by the server only (`Server._close`), after its scope is cancelled
and its reader task has taken it out of the set: a descriptor closed from outside drops out of the epoll set
without an event (trio's `notify_closing` wakes only trio's own waiters), so nothing would end that connection,
and its number, free again, would be the next accepted socket's.
"""

from __future__ import annotations

import select
import time
from collections.abc import Callable
from typing import Any

import trio

#: a pass over the ready connections yields to the other tasks (the flusher, timers) once it took this long;
#: the connections not served yet are still ready (level-triggered) and are reported again by the next poll
PASS_YIELD_S = 0.002
#: a pass that took less than this polls again at once; a longer one goes back to trio first. Why: under load
#: (the standard switch load's PUBLISH frames) polling again at once measured a higher CPU per delivery, likely
#: because the hub read ahead of the flusher and more states were routed only to be replaced in the outboxes
#: (docs/switch.md, "One read hub"); a lock step's PINGs take tens of microseconds a pass
REPOLL_BELOW_S = 0.0005
#: at most this many ready connections per poll (the rest are reported by the next one)
MAX_EVENTS = 512


class ReadHub:
    """The epoll set of the plain-TCP connections that are waiting for input, and the task that serves them."""

    def __init__(self, ready: Callable[[Any], None]):
        self._ready = ready  # called with the connection record of each readable descriptor
        self._ep = select.epoll()
        self._by_fd: dict[int, Any] = {}
        self.passes = 0  # polls that found at least one connection ready (tests, notes)

    def __len__(self) -> int:
        return len(self._by_fd)

    def add(self, conn: Any) -> None:
        """Serve `conn` (its `fd`) from the hub until `discard`. Registered once, level-triggered. A no-op once
        the hub has stopped: the server is stopping, and the connection's task is being cancelled with it."""
        if self._ep.closed:
            return
        self._ep.register(conn.fd, select.EPOLLIN)
        self._by_fd[conn.fd] = conn

    def discard(self, conn: Any) -> None:
        """Stop serving `conn` (handed to its own task, or gone); a no-op if it is not in the set."""
        if self._by_fd.get(conn.fd) is conn:
            del self._by_fd[conn.fd]
            try:
                self._ep.unregister(conn.fd)
            except (OSError, ValueError):  # the descriptor closed (the kernel dropped it), or the hub stopped
                pass

    async def run(self) -> None:
        """Wait until some registered connection is readable, serve every ready one, repeat; closes the set
        when cancelled (the server stopping)."""
        ep, by_fd, ready = self._ep, self._by_fd, self._ready
        epfd = ep.fileno()
        try:
            while True:
                await trio.lowlevel.wait_readable(epfd)
                began = time.perf_counter()
                # after a cheap pass, poll again before going back to trio: what arrived meanwhile (clients of
                # a lock step send one PING after the other) costs a system call instead of a scheduler pass
                while events := ep.poll(0, MAX_EVENTS):
                    self.passes += 1
                    pass_began = time.perf_counter()
                    for fd, _mask in events:
                        conn = by_fd.get(fd)
                        if conn is not None:  # (else discarded earlier in this pass)
                            ready(conn)
                        if time.perf_counter() - began >= PASS_YIELD_S:
                            await trio.lowlevel.checkpoint()
                            began = time.perf_counter()
                    if time.perf_counter() - pass_began >= REPOLL_BELOW_S:
                        break  # real work (PUBLISH frames): trio's turn, so the flusher and timers get theirs
        finally:
            trio.lowlevel.notify_closing(epfd)
            ep.close()
