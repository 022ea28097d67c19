"""A fixed piece of CPU work, timed before and after each benchmark run: how fast the machine was then.

Why: a CPU figure of a small VM moves with the VM, not only with the code. In `bench e2e`'s full run of
2026-12-01 23:43-00:05 UTC (one CPU, nothing else running) every system's CPU per viewer-second in the third
repetition was 15-45 % above the first two, the idle runs' and the load generator's own CPU for the same work
included, and steal time is not in these counters (the kernel has CONFIG_PARAVIRT_TIME_ACCOUNTING); this loop
alone took 210-255 ms at 23:37 and 226-363 ms at 00:05. So each run records the machine's speed beside its
figures (`machine_work_ms`), and a CPU figure can also be read at the sitting's median speed (`at_median_speed`):
a reader sees which repetitions ran on a slow machine, and what the code's figure is without the machine's
part. The work is interpreted Python (dict lookups and integer adds): the load generator's kind of work; the
brokers' C is slowed by the same neighbours by other amounts, so the correction is approximate, and the raw
figures stay the ones reported first.
"""

from __future__ import annotations

import statistics
import time

#: dict lookups per timing: about 50 ms of one core on the machines of round 9
LOOKUPS = 400_000
#: timings per reading; the median is the reading (a preemption inflates one timing, not the median)
REPEATS = 5


def work_ms(lookups: int = LOOKUPS, repeats: int = REPEATS) -> float:
    """The median CPU time of this thread, in ms, over `repeats` timings of the fixed work."""
    table = {i: i for i in range(2000)}
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.thread_time_ns()
        acc = 0
        for i in range(lookups):
            acc += table[i % 2000]
        times.append((time.thread_time_ns() - t0) / 1e6)
    return statistics.median(times)


def at_median_speed(value: float | None, run_ms: float | None, reference_ms: float | None) -> float | None:
    """A CPU figure measured while the fixed work took `run_ms`, as it would read at `reference_ms` (the CPU a
    fixed piece of work takes scales with the machine's slowness); None where any of them is unknown."""
    if value is None or not run_ms or not reference_ms:
        return None
    return value * reference_ms / run_ms
