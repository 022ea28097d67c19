"""The benchmarks' per-process CPU reader: fine where Linux keeps nanoseconds, never below what the ticks show."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from sims.bench import proc_cpu
from sims.bench.proc_cpu import ProcessCpu

LINUX_SCHEDSTAT = Path("/proc/self/task").is_dir() and Path("/proc/self/schedstat").exists()

#: a child that spins on the CPU for about `s` seconds on its main thread (optionally in a thread that ends),
#: then sleeps until killed
SPIN = """
import sys, threading, time
def spin(s):
    t = time.thread_time() + s
    while time.thread_time() < t:
        pass
main_s, thread_s = float(sys.argv[1]), float(sys.argv[2])
print("ready", flush=True)
sys.stdin.readline()
if thread_s:
    th = threading.Thread(target=spin, args=(thread_s,)); th.start(); th.join()
spin(main_s)
print("done", flush=True)
time.sleep(60)
"""


def _child(main_s: float, thread_s: float = 0.0) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", SPIN, str(main_s), str(thread_s)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "ready"
    return proc


def _measure(proc: subprocess.Popen) -> tuple[float, ProcessCpu]:
    cpu = ProcessCpu(proc.pid)
    c0 = cpu()
    proc.stdin.write("go\n")
    proc.stdin.flush()
    assert proc.stdout.readline().strip() == "done"
    return cpu() - c0, cpu


@pytest.mark.skipif(not LINUX_SCHEDSTAT, reason="needs Linux's per-thread schedstat")
def test_a_spin_is_measured_finer_than_a_tick():
    proc = _child(0.123)
    try:
        spent, cpu = _measure(proc)
        assert cpu.fine and cpu.clock == "ns"
        assert 0.123 - 0.003 <= spent <= 0.123 + 0.02, spent  # the spin's own overshoot is microseconds
        # not a whole number of ticks, as a psutil reading is (a nanosecond figure lands within 10 ns of one
        # about once in 10^6 runs)
        assert abs(spent / proc_cpu.TICK_S - round(spent / proc_cpu.TICK_S)) > 1e-6
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.skipif(not LINUX_SCHEDSTAT, reason="needs Linux's per-thread schedstat")
def test_a_thread_that_ends_between_readings_is_not_lost():
    """The ended thread's nanoseconds leave the live threads' sum; the thread group's ticks keep them."""
    proc = _child(0.05, thread_s=0.3)
    try:
        spent, cpu = _measure(proc)
        assert spent >= 0.3 + 0.05 - 0.03, spent
        assert cpu.clock == "ticks"  # and the report says so
    finally:
        proc.kill()
        proc.wait()


def test_a_process_that_is_gone_reads_as_its_last_figure():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    cpu = ProcessCpu(proc.pid)
    first = cpu()
    proc.wait()
    time.sleep(0.05)
    assert cpu() == first  # reaped: no /proc entry, no exception


def test_without_schedstat_the_coarse_figure_is_used(monkeypatch):
    proc = _child(0.05)
    try:
        monkeypatch.setattr(ProcessCpu, "_fine", lambda self: None)
        spent, cpu = _measure(proc)
        assert not cpu.fine and cpu.clock == "ticks"
        assert abs(spent / proc_cpu.TICK_S - round(spent / proc_cpu.TICK_S)) < 1e-6  # whole ticks
        assert 0.0 <= spent <= 0.05 + 0.05
    finally:
        proc.kill()
        proc.wait()
