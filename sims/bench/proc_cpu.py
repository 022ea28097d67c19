"""A peer process's CPU time, to the microsecond where Linux says so, for the benchmarks' per-process figures.

Why: psutil's `cpu_times` reads /proc/PID/stat, whose user and system times come in clock ticks (10 ms here).
A broker that spends 0.35 ms of CPU per viewer-second in `bench e2e` spends ~65 ticks in a whole run, so one
tick is 1.5 % of the figure and two runs of the same code read 0.350 and 0.361: the 5x target was once missed
by less than one tick. The scheduler keeps each thread's time on the CPU in nanoseconds
(/proc/PID/task/TID/schedstat, first field: `sum_exec_runtime`, user and system together), which is what this
reads. A thread that ends between two readings takes its time with it from that sum (the thread group's stat
keeps it), so each reading also takes the coarse figure, and a difference where the coarse one exceeds the
fine one by more than its rounding (a tick per thread, a tick more for the reading itself) is the coarse one:
never less than what the ticks show. Elsewhere (no /proc, no schedstat) psutil's figure is used as it is.
"""

from __future__ import annotations

import os
from pathlib import Path

TICK_S = 1.0 / os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 0.01


class ProcessCpu:
    """`cpu()`: the process's CPU seconds, cumulative; only differences between two calls mean anything.

    The first call is the origin; every later call returns the origin's coarse figure plus the CPU since, fine
    where the fine sum accounts for all the coarse one shows (see the module's docstring). A process that is
    gone reads as its last figure, as psutil's `cpu_times` fails then."""

    def __init__(self, pid: int):
        self.pid = pid
        self._origin: tuple[float, float] | None = None
        self._last = 0.0
        self.fine = Path(f"/proc/{pid}/task").is_dir() and self._fine() is not None
        self.ticks_used = not self.fine  # a reading fell back to the ticks (a thread ended), or all do

    @property
    def clock(self) -> str:
        """What the last figure was counted in, for the report: "ns" or "ticks"."""
        return "ticks" if self.ticks_used else "ns"

    def _fine(self) -> float | None:
        """Sum of the live threads' nanoseconds on the CPU, in seconds; None where it cannot be read."""
        total, read = 0, 0
        try:
            for tid in os.listdir(f"/proc/{self.pid}/task"):
                try:
                    with open(f"/proc/{self.pid}/task/{tid}/schedstat", "rb") as f:
                        total += int(f.read().split()[0])
                    read += 1
                except FileNotFoundError:  # the thread ended while we listed (or no schedstat: see below)
                    continue
        except (OSError, ValueError, IndexError):
            return None
        return total / 1e9 if read else None  # a kernel without schedstat has none for any thread

    def _coarse(self) -> tuple[float, int] | None:
        """(user + system seconds of the whole thread group, in ticks; its thread count) from /proc/PID/stat,
        or psutil's figure where there is no /proc."""
        try:
            with open(f"/proc/{self.pid}/stat", "rb") as f:
                fields = f.read().rsplit(b")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) * TICK_S, int(fields[17])
        except FileNotFoundError:
            return None
        except OSError:
            pass
        import psutil

        try:
            t = psutil.Process(self.pid).cpu_times()
        except psutil.Error:
            return None
        return t.user + t.system, 1

    def __call__(self) -> float:
        coarse = self._coarse()
        if coarse is None:
            return self._last
        fine = self._fine() if self.fine else None
        if fine is None:
            self.ticks_used = True
            self._last = coarse[0]
            return self._last
        if self._origin is None:
            self._origin = (coarse[0], fine)
            self._last = coarse[0]
            return self._last
        d_coarse, d_fine = coarse[0] - self._origin[0], fine - self._origin[1]
        rounding = (coarse[1] + 1) * TICK_S
        self.ticks_used = d_coarse - d_fine > rounding
        self._last = self._origin[0] + (d_coarse if self.ticks_used else d_fine)
        return self._last
