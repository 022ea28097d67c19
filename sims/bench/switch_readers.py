"""The switch benchmark's load-generator readers: viewers' sockets in an epoll loop, tallying deliveries.

Why apart from the benchmark's driver: a reader runs in its own process, and its costs (a regex scan per read,
numpy dedup every 10 ms) decide whether the load generator or the server is the bottleneck; kept in one place
they can be tuned and tested without the server run around them.
"""

from __future__ import annotations

import math
import os
import re
import select
import socket
import time
from typing import Any

import numpy as np

LAT_BIN = 1e-4  # latency histogram: 0.1 ms bins up to 5 s ...
LAT_FINE = 50_000
LAT_COARSE = 0.01  # ... then 10 ms bins up to 120 s; the last bin holds everything slower
LAT_BINS = LAT_FINE + 11_501

# ---------------------------------------------------------------------------------------------- accounting
class Tally:
    """Useful deliveries (once per viewer, entity, seq) and a latency histogram, during the window only.

    Vectorised: the load generator counts several hundred thousand deliveries per second in one Python
    process, so reads only pull the 16-byte payload heads out with one regex scan (every payload ends in 32
    zero bytes and a fixed trailer), and every 10 ms the collected heads are deduplicated and binned in numpy.
    """

    REC = np.dtype([("t", "<f8"), ("e", "<u4"), ("s", "<u4")])

    def __init__(self, n_viewers: int, n_entities: int):
        self.last = np.zeros((n_viewers, n_entities), dtype=np.uint32)
        self.count = 0
        self.dups = 0
        self.hist = np.zeros(LAT_BINS, dtype=np.int64)
        self.window = (math.inf, math.inf)  # deliveries received in [start, end) are counted
        self.pending: list[tuple[int, list[bytes], float]] = []

    def add(self, v: int, heads: list[bytes], t_recv: float) -> None:
        """Queue a read's payload heads; counted at the next `flush` (batching keeps the reader cheap)."""
        self.pending.append((v, heads, t_recv))

    def flush(self) -> None:
        """Deduplicate and bin what was queued: a seq newer than the last seen per (viewer, entity), received
        inside the window, counts once."""
        pending, self.pending = self.pending, []
        if not pending:
            return
        counts = np.array([len(h) for _, h, _ in pending])
        rec = np.frombuffer(b"".join(b"".join(h) for _, h, _ in pending), dtype=self.REC)
        v = np.repeat(np.array([x[0] for x in pending], dtype=np.int64), counts)
        t_recv = np.repeat(np.array([x[2] for x in pending]), counts)
        e = rec["e"].astype(np.int64)
        s = rec["s"].astype(np.int64)
        key = (v << 52) | (e << 32) | s
        _, first = np.unique(key, return_index=True)
        dups = len(rec) - len(first)
        first.sort()
        v, e, s, t_sent, t_recv = v[first], e[first], s[first], rec["t"][first], t_recv[first]
        new = s > self.last[v, e]
        np.maximum.at(self.last, (v, e), s.astype(np.uint32))
        n_new = int(new.sum())
        self.dups += dups + len(s) - n_new
        new &= (t_recv >= self.window[0]) & (t_recv < self.window[1])
        n_new = int(new.sum())
        if n_new:
            self.count += n_new
            lat = np.maximum(t_recv[new] - t_sent[new], 0.0)
            b = np.where(lat < LAT_FINE * LAT_BIN, lat / LAT_BIN,
                         LAT_FINE + (lat - LAT_FINE * LAT_BIN) / LAT_COARSE).astype(np.int64)
            np.clip(b, 0, LAT_BINS - 1, out=b)
            self.hist += np.bincount(b, minlength=LAT_BINS)

    def quantile(self, q: float) -> float | None:
        """Latency quantile in ms from the histogram (bin centre); None before any delivery."""
        total = int(self.hist.sum())
        if not total:
            return None
        b = int(np.searchsorted(np.cumsum(self.hist), q * total))
        if b < LAT_FINE:
            return (b + 0.5) * LAT_BIN * 1000.0
        return (LAT_FINE * LAT_BIN + (b - LAT_FINE + 0.5) * LAT_COARSE) * 1000.0


class Scanner:
    """Pulls the 16-byte payload heads out of a byte stream, keeping an incomplete tail for the next read."""

    def __init__(self, pattern: bytes, keep: int = 128):
        self.re = re.compile(pattern, re.S)
        self.buf = b""
        self.keep = keep

    def feed(self, data: bytes) -> list[bytes]:
        """The heads complete in what has arrived so far (a record split across reads is found next time)."""
        buf = self.buf + data if self.buf else data
        heads = self.re.findall(buf)
        if heads:
            end = buf.rfind(heads[-1]) + 16 + 34  # past the last record (head, padding, trailer)
            rest = buf[end:]
        else:
            rest = buf
        self.buf = rest[-self.keep :] if len(rest) > self.keep else rest
        return heads


class Ready:
    """Counts a marker (subscription acknowledged) across reads until `need` have been seen."""

    def __init__(self, marker: bytes, need: int):
        self.marker, self.need, self.tail = marker, need, b""

    def feed(self, data: bytes) -> bool:
        """True once `need` markers have arrived (a marker split across reads is still counted once)."""
        buf = self.tail + data
        self.need -= buf.count(self.marker) - self.tail.count(self.marker)
        self.tail = buf[-len(self.marker) :]
        return self.need <= 0

class ReaderLoop:
    """Sockets in one epoll loop: a read costs one syscall and a regex scan, not a task switch."""

    def __init__(self, tally: Tally | None):
        self.ep = select.epoll()
        self.handlers: dict[int, Any] = {}
        self.socks: list[socket.socket] = []
        self.tally = tally
        self.ready = 0
        self.stop = False

    def add(self, sock: socket.socket, handler) -> None:
        """Watch a socket (non-blocking, no Nagle); `handler(data, t)` gets each read."""
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setblocking(False)
        self.socks.append(sock)
        self.handlers[sock.fileno()] = handler
        self.ep.register(sock.fileno(), select.EPOLLIN)

    def viewer(self, v: int, pattern: bytes, ready: Ready):
        """A read handler for viewer `v`: notes its subscription ack, then tallies the payload heads it reads."""
        scan = Scanner(pattern)
        state = {"ready": False}

        def handle(data: bytes, t: float) -> None:
            if not state["ready"] and ready.feed(data):
                state["ready"] = True
                self.ready += 1
            heads = scan.feed(data)
            if heads:
                self.tally.add(v, heads, t)

        return handle

    def run(self, on_tick=None) -> None:
        """Read until `stop`; every 10 ms flush the tally and call `on_tick(self)`."""
        next_flush = time.monotonic() + 0.01
        while not self.stop:
            events = self.ep.poll(0.005)
            t = time.time()
            for fd, _ in events:
                try:
                    data = os.read(fd, 262144)
                except BlockingIOError:
                    continue
                except OSError:
                    data = b""
                if not data:
                    self.ep.unregister(fd)
                    continue
                self.handlers[fd](data, t)
            if time.monotonic() >= next_flush:
                if self.tally is not None:
                    self.tally.flush()
                if on_tick is not None:
                    on_tick(self)
                next_flush = time.monotonic() + 0.01
        for s in self.socks:
            s.close()


def reader_process(driver, viewers, n_entities: int, shared, pipe) -> None:
    """One load-generator reader process: connects its share of the viewers and tallies what they get."""
    ready_v, w0, w1, stop = shared
    tally = Tally(len(viewers), n_entities)
    loop = ReaderLoop(tally)
    for k, cells in enumerate(viewers):
        s = socket.create_connection(("127.0.0.1", driver.port))
        hello, ready = driver.viewer_hello(cells)
        s.sendall(hello)
        loop.add(s, loop.viewer(k, driver.pattern, ready))
    reported = 0

    def tick(lp: ReaderLoop) -> None:
        nonlocal reported
        if lp.ready > reported:
            with ready_v.get_lock():
                ready_v.value += lp.ready - reported
            reported = lp.ready
        tally.window = (w0.value, w1.value)
        lp.stop = bool(stop.value)

    loop.run(tick)
    tally.flush()
    pipe.send((tally.count, tally.dups, tally.hist, time.process_time()))
    pipe.close()
