"""The coordinator's side of its viewer processes: fork them, start them on the server, send each tick, gather
their measures into the report, and name any that dies.

Every wait is bounded: `timeout` for the processes to connect and for each send (a process that does not read
its ticks is declared dead, not waited for), and for the reports at the end. A dead process is named in the
report (`viewer_processes.deaths`: its index, pid, why, the tick, how many viewers it held) and the run goes on
with the others; its viewers' figures up to its death are lost (it reports only at the end), and the report
says how many viewers the figures rest on. `close` joins every child, killing one that does not end in time,
so no process is left behind.
"""

from __future__ import annotations

import multiprocessing as mp
import socket
import time
from collections import deque

import trio

from entitynet import protocol as P
from sims.engine.measure import Measure, Tally
from sims.viewers import wire
from sims.viewers.child import child_main
from sims.viewers.share import share_of

#: a report's `viewers` counters, summed over the processes
VIEWER_COUNTS = ("street", "roof", "measured", "counted", "deliveries", "leaves", "bytes")


class ViewerProcesses:
    """`n` forked viewer processes for the run `config` (see the module docstring). Fork before the event loop
    runs (in the constructor); `connect`, `tick`, `finish` from the shell's trio loop; `close` at the end."""

    def __init__(self, n: int, topo, schedule, config, timeout: float = 30.0):
        if not 1 <= n <= max(config.viewers, 1):
            raise ValueError(f"viewer processes must be between 1 and the number of viewers ({config.viewers}), "
                             f"got {n}")
        self.n, self.config, self.timeout = n, config, timeout
        self.shares = [share_of(config.viewers, n, i) for i in range(n)]
        ctx = mp.get_context("fork")
        self.procs: list[mp.Process] = []
        self._socks: list[socket.socket] = []
        for i in range(n):
            parent, child = socket.socketpair()
            # the child closes its copies of the coordinator's ends (its own and its elder siblings'), so that
            # the coordinator's close of one is that process's end of file
            inherited = [*self._socks, parent]
            p = ctx.Process(target=child_main, args=(child, topo, schedule, config, self.shares[i], inherited),
                            name=f"entitynet-sim-viewers-{i}", daemon=True)
            p.start()
            child.close()
            self._socks.append(parent)
            self.procs.append(p)
        self._streams: list[trio.SocketStream | None] = [None] * n
        self._readers = [wire.FrameReader() for _ in range(n)]
        self._pending: list[deque[dict]] = [deque() for _ in range(n)]  # frames read, not yet taken
        self.reports: list[dict | None] = [None] * n
        self.deaths: list[dict] = []
        self.k = -1
        self.tick_wait_s = 0.0  # wall seconds the coordinator spent handing ticks over (a slow reader shows here)

    @property
    def pids(self) -> list[int]:
        """The children's process ids (for tests, and to kill one on purpose)."""
        return [p.pid for p in self.procs]

    def live(self) -> list[int]:
        """The processes not declared dead."""
        return [i for i, s in enumerate(self._streams) if s is not None]

    def _lose(self, i: int, why: str) -> None:
        s = self._streams[i]
        self._streams[i] = None
        if s is not None:
            s.socket.close()
        code = self.procs[i].exitcode
        self.deaths.append({"index": i, "pid": self.procs[i].pid, "why": why if code is None else
                            f"{why} (exit code {code})", "tick": self.k, "viewers": len(self.shares[i])})
        if code is None:  # declared dead but running (stopped, stuck, too slow): it ends now, not at `close`,
            self.procs[i].kill()  # so it holds no server connections and no CPU for the rest of the run

    async def _read(self, i: int) -> dict:
        s, pending = self._streams[i], self._pending[i]
        while True:
            pending.extend(self._readers[i].frames())  # a read may bring several frames: none is dropped
            if pending:
                return pending.popleft()
            data = await s.receive_some(1 << 20)
            if not data:
                raise EOFError("its socket closed (the process ended)")
            self._readers[i].feed(data)

    async def connect(self, address: tuple[str, int], token: str = "") -> None:
        """Start every process on the server at `address`; wait (up to the timeout) for their connections."""
        for i, sock in enumerate(self._socks):
            self._streams[i] = trio.SocketStream(trio.socket.from_stdlib_socket(sock))
        start = wire.encode("start", host=str(address[0]), port=int(address[1]), token=token)
        for i in self.live():  # every process starts at once (each builds its share and connects)...
            await self._exchange(i, start, None)
        for i in self.live():  # ...then each is waited for
            await self._exchange(i, b"", "ready")

    async def _exchange(self, i: int, frame: bytes, answer: str | None) -> dict | None:
        """Send `frame` to process i (if any) and wait for its `answer` frame (if one is named); a process that
        fails is declared dead."""
        try:
            with trio.fail_after(self.timeout):
                if frame:
                    await self._streams[i].send_all(frame)
                if answer is None:
                    return None
                got = await self._read(i)
        except trio.TooSlowError:
            self._lose(i, f"no {answer} within {self.timeout:g} s")
            return None
        except (EOFError, OSError, trio.BrokenResourceError, trio.ClosedResourceError, wire.WireError) as exc:
            self._lose(i, str(exc) or type(exc).__name__)
            return None
        if got["t"] != answer:
            self._lose(i, f"sent {got['t']} where {answer} was due")
            return None
        return got

    async def tick(self, k: int, msgs: list[list[P.Message]]) -> None:
        """Tick `k` to every live process, with the payloads the publishers send in it (`msgs`: per publisher
        connection, as `Sim.step` gives them). Send it before the publishes go to the server, so a process
        knows a payload before its first UPDATE arrives."""
        self.k = k
        pub = [[m.entity, m.payload] for ms in msgs for m in ms if isinstance(m, P.Publish)]
        unpub = [m.entity for ms in msgs for m in ms if isinstance(m, P.Unpublish)]
        frame = wire.encode("tick", k=k, pub=pub, unpub=unpub, sent=time.monotonic())
        t0 = time.monotonic()
        for i in self.live():
            if self.procs[i].exitcode is not None:
                self._lose(i, "its process ended")
                continue
            try:
                with trio.fail_after(self.timeout):
                    await self._streams[i].send_all(frame)
            except trio.TooSlowError:
                self._lose(i, f"did not read its tick within {self.timeout:g} s")
            except (OSError, trio.BrokenResourceError, trio.ClosedResourceError):
                self._lose(i, "its socket broke (the process ended)")
        self.tick_wait_s += time.monotonic() - t0

    async def finish(self) -> None:
        """Stop every live process and gather its report (each waited for up to the timeout); a report that
        does not read is named among the deaths here, before the live output's last lines."""
        stop = wire.encode("stop")
        for i in self.live():
            report = await self._exchange(i, stop, "report")
            for _ in range(report["error_frames"] if report is not None else 0):
                errors = await self._exchange(i, b"", "errors")
                if errors is None:  # named dead by `_exchange`: its report goes with it
                    report = None
                    break
                try:
                    wire.add_errors(report, errors)
                except wire.WireError as exc:
                    self._lose(i, str(exc))
                    report = None
                    break
            self.reports[i] = report
        self._readable()

    def _readable(self) -> list[tuple[dict, dict[str, Tally], int]]:
        """Each report that reads, as (viewer counts, tallies per group, SUBSCRIBEs); one that does not is
        dropped and named dead (once: it is dropped)."""
        out = []
        for i, r in enumerate(self.reports):
            if r is None:
                continue
            try:
                counts = {k: int(r["viewers"].get(k, 0)) for k in VIEWER_COUNTS}
                tallies = {str(g): Tally([float(x) for x in t["errors"]], int(t["visible"]), int(t["missed"]),
                                         int(t["shown"]), int(t["stale"]), int(t["viewer_samples"]))
                           for g, t in r["tallies"].items()}
                out.append((counts, tallies, int(r["subscribe_msgs"])))
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                self.reports[i] = None
                self.deaths.append({"index": i, "pid": self.procs[i].pid, "tick": self.k,
                                    "why": f"sent a report that does not read ({exc!r:.80})",
                                    "viewers": len(self.shares[i])})
        return out

    def deliveries(self) -> int:
        """UPDATEs delivered to the viewers of the processes whose reports read (for the run's last line)."""
        return sum(counts["deliveries"] for counts, _, _ in self._readable())

    def merge(self, rep: dict) -> dict:
        """The run's report with the viewers' counts and the truth-against-viewer figures of every process
        that reported, and a `viewer_processes` section naming the dead."""
        measure = Measure()
        viewers = dict.fromkeys(VIEWER_COUNTS, 0)
        subscribe_msgs = 0
        for counts, tallies, subs in self._readable():
            for k, n in counts.items():
                viewers[k] += n
            subscribe_msgs += subs
            for g, t in tallies.items():
                acc: Tally = measure.tallies[g]
                acc.errors += t.errors
                for f in ("visible", "missed", "shown", "stale", "viewer_samples"):
                    setattr(acc, f, getattr(acc, f) + getattr(t, f))
        rep["viewers"] = viewers
        rep["truth_vs_viewer"] = {**measure.summary(), "measured_viewers": viewers["measured"],
                                  "counted_viewers": viewers["counted"]}
        rep["viewer_processes"] = {
            "processes": self.n, "measured_viewers": viewers["measured"],
            "viewers": self.config.viewers, "subscribe_msgs": subscribe_msgs, "deaths": list(self.deaths),
            "cpu_s": [None if r is None else round(r["cpu_s"], 2) for r in self.reports],
            "coordinator_tick_wait_s": round(self.tick_wait_s, 3),
            "tick_delay_p99_ms": [None if r is None else round(r["tick_delay_p99_ms"], 1) for r in self.reports],
            "note": "each process measured its own viewers against the truth it stepped from the seed; the "
                    "figures are those processes' tallies summed (the error list in process order); "
                    "tick_delay_p99_ms: how late each process took up its ticks (a process behind real time "
                    "subscribes late and counts the joins it has not received yet as missed)"}
        return rep

    def close(self) -> None:
        """Close every socket and join every child (SIGKILL to one still running after 2 s)."""
        for s in self._socks:
            try:
                s.close()
            except OSError:
                pass
        deadline = time.monotonic() + 2.0
        for p in self.procs:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join(1.0)
