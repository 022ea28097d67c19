"""File descriptors: raise the soft limit at start, and admit connections only while descriptors are left.

Why: every client is one socket, and a server that runs out of descriptors cannot even accept a connection to
tell it "server full"; worse, `accept` then fails in a loop (EMFILE) and every other file operation fails too.
So the server raises its soft RLIMIT_NOFILE to the hard limit at start (and says so), counts the sockets it
holds, and refuses new clients with SERVER_FULL while `reserve` descriptors are still free: enough to accept
a connection, send the refusal and close it, and for the odd file or thread the process opens meanwhile.

The count is kept by the shell (`enter`/`leave` around every accepted socket) rather than by listing
/proc/self/fd on every accept, which costs milliseconds with 20,000 sockets open; `watch` re-measures what
else the process holds (`others`) every couple of seconds.
"""

from __future__ import annotations

import logging
import os

import trio

from entitynet.server import logs

try:
    import resource
except ImportError:  # not on Windows: no limit to raise, and the guard only counts clients
    resource = None  # type: ignore[assignment]

UNLIMITED = 1 << 30  # stands in for "no known limit"


def soft_limit() -> int:
    """The current soft RLIMIT_NOFILE (UNLIMITED where there is none)."""
    if resource is None:
        return UNLIMITED
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    return UNLIMITED if soft == resource.RLIM_INFINITY else int(soft)


def raise_soft_limit() -> tuple[int, int]:
    """Raise the soft RLIMIT_NOFILE to the hard limit (bounded by the kernel's nr_open); (before, after).

    Logs what it did: a server's capacity in clients is bounded by this number, so the operator should see it.
    """
    if resource is None:
        return UNLIMITED, UNLIMITED
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = hard
    if hard == resource.RLIM_INFINITY:
        target = _nr_open()
    if soft != resource.RLIM_INFINITY and soft < target:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
        except (ValueError, OSError) as exc:
            logs.event("cannot raise the descriptor limit", logging.WARNING, soft=soft, hard=hard, reason=exc)
            return soft, soft
        logs.event("descriptor limit raised", soft_before=soft, soft=target, hard=_show(hard))
        return soft, target
    logs.event("descriptor limit", soft=_show(soft), hard=_show(hard))
    return soft, soft


def _nr_open() -> int:
    try:
        with open("/proc/sys/fs/nr_open") as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return 1 << 20


def _show(limit: int) -> str | int:
    return "unlimited" if resource is not None and limit == resource.RLIM_INFINITY else limit


def count_open_fds() -> int | None:
    """Descriptors this process holds now, or None where the platform does not tell."""
    for path in ("/proc/self/fd", "/dev/fd"):
        try:
            return len(os.listdir(path)) - 1  # the listing's own descriptor
        except OSError:
            continue
    return None


class Admission:
    """Counts the sockets the server holds and says whether one more may be admitted.

    `clients` are protocol connections (TCP, TLS, WebSocket, including those still in the TLS handshake or the
    WebSocket upgrade): they count against `max_clients`. `sockets` are all accepted sockets (clients, refused
    ones being told so, HTTP): with `others` (listeners, files, everything else the process holds) they count
    against the descriptor limit minus `reserve`.
    """

    def __init__(self, max_clients: int, reserve: int = 64, limit: int | None = None) -> None:
        self.max_clients = max_clients
        self.reserve = reserve
        self.limit = soft_limit() if limit is None else limit
        self.others = 0
        self.clients = 0
        self.sockets = 0
        self.refused = 0  # connections refused since the start (for logs and tests)

    def measure(self) -> None:
        """Re-read the limit and what the process holds besides our sockets."""
        self.limit = soft_limit()
        n = count_open_fds()
        if n is not None:
            self.others = max(0, n - self.sockets)

    def fds_left(self) -> int:
        """Descriptors still free under the soft limit: our sockets and everything else the process holds
        count against it."""
        return self.limit - self.others - self.sockets

    def enter(self, client: bool) -> str | None:
        """Count one accepted socket; the reason to refuse it (None: admit). Always pair with `leave`."""
        reason = None
        if self.fds_left() <= self.reserve:
            reason = f"descriptor limit ({self.limit}) nearly reached"
        elif client and self.clients >= self.max_clients:
            reason = f"max_clients ({self.max_clients}) reached"
        self.sockets += 1
        if reason is None and client:
            self.clients += 1
        if reason is not None:
            self.refused += 1
        return reason

    def leave(self, client: bool, admitted: bool) -> None:
        """Undo one `enter`; `admitted` is whether `enter` admitted it (only admitted clients were counted as
        clients)."""
        self.sockets -= 1
        if client and admitted:
            self.clients -= 1

    async def watch(self, every: float = 2.0) -> None:
        """Re-measure periodically (other descriptors come and go: files, threads, links)."""
        while True:
            self.measure()
            await trio.sleep(every)
