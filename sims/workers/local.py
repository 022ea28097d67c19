"""Workers as forked processes on this machine, over pipes: the local transport of `WorkerSim`.

Why fork: a child starts with the map and the schedule already loaded (copy-on-write), so a worker is ready in
milliseconds instead of loading them again, and it runs the same `WorkerCore` as a worker on another machine.
Each child dies with its parent (PR_SET_PDEATHSIG) and also ends when its pipe closes (so it needs no silence
timeout: a paused coordinator is not a dead one); it ignores SIGINT (a
terminal's Ctrl-C reaches the whole process group: the coordinator stops the run and then its workers, in
order, with no traceback from any child). `close` joins every child, killing one that does not end in time.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import socket
import time
from multiprocessing.connection import Connection, wait

from sims.engine.collector import settle_after_start
from sims.engine.schedule import Schedule
from sims.workers.run import RefusedRun, WorkerShare, config_from_wire, run_digests
from sims.workers.worker import WorkerCore


def _child(conn: Connection, topo, schedule: Schedule | None, index: int) -> None:
    """A forked worker: frames from the pipe through `WorkerCore`, its answers back, until stop or EOF."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from entitynet.cluster.natsd import die_with_parent

    tie = die_with_parent()
    if tie is not None:
        tie()
    digests = run_digests(topo, schedule)

    def build(config: dict, want: dict, i: int, n: int) -> WorkerShare:
        if any(want.get(k) != digests[k] for k in digests):
            raise RefusedRun(f"another map or schedule (coordinator {want}, here {digests})")
        return WorkerShare(topo, schedule, config_from_wire(config), i, n)

    core = WorkerCore(f"local-{index}", socket.gethostname(), os.getpid(), build)
    settled = False
    try:
        while True:
            data = conn.recv_bytes()
            for frame in core.receive(data, time.monotonic()):
                conn.send_bytes(frame)
            if not settled and core.share is not None and core.share.k >= 0:  # its start done: freeze it
                settle_after_start()
                settled = True
            if core.runs_done:
                return
    except (EOFError, OSError, BrokenPipeError):
        return  # the coordinator is gone


class LocalWorkers:
    """`n` forked workers holding `topo` and `schedule`; a `Link` for `WorkerSim`."""

    def __init__(self, n: int, topo, schedule: Schedule | None):
        if n < 1:
            raise ValueError(f"at least one worker, got {n}")
        ctx = mp.get_context("fork")
        self.conns: list[Connection | None] = []
        self.procs: list[mp.Process] = []
        self._gone: list[tuple[int, str]] = []
        for i in range(n):
            parent, child = ctx.Pipe(duplex=True)
            p = ctx.Process(target=_child, args=(child, topo, schedule, i), name=f"entitynet-sim-worker-{i}",
                            daemon=True)
            p.start()
            child.close()
            self.conns.append(parent)
            self.procs.append(p)

    @property
    def pids(self) -> list[int]:
        """The children's process ids (for tests, and to kill one on purpose)."""
        return [p.pid for p in self.procs]

    def _lose(self, i: int, why: str) -> None:
        c = self.conns[i]
        if c is not None:
            self.conns[i] = None
            c.close()
            code = self.procs[i].exitcode
            self._gone.append((i, why if code is None else f"{why} (exit code {code})"))

    def send(self, index: int, data: bytes) -> None:
        """Send a frame; a broken pipe marks the worker gone."""
        c = self.conns[index]
        if c is None:
            return
        try:
            c.send_bytes(data)
        except OSError:
            self._lose(index, "its pipe broke (the process ended)")

    def recv(self, timeout: float) -> list[bytes]:
        """Frames from any worker, waiting up to `timeout` s for the first."""
        live = {c: i for i, c in enumerate(self.conns) if c is not None}
        out = []
        for c in wait(list(live), timeout):
            try:
                while True:
                    out.append(c.recv_bytes())
                    if not c.poll():
                        break
            except (EOFError, OSError):
                self.procs[live[c]].join(0.2)
                self._lose(live[c], "its process ended")
        return out

    def gone(self) -> list[tuple[int, str]]:
        """Workers whose pipe closed since the last call."""
        out, self._gone = self._gone, []
        return out

    def close(self) -> None:
        """Close every pipe and join every child (SIGKILL to one still running after 2 s)."""
        for i, c in enumerate(self.conns):
            if c is not None:
                c.close()
                self.conns[i] = None
        deadline = time.monotonic() + 2.0
        for p in self.procs:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join(1.0)
