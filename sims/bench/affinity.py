"""Which CPUs a benchmark, its load generator and the servers it starts run on (`entitynet bench --cpus`).

Why: on a small VM a broker that wakes a few dozen times a second costs what the vCPU it wakes on costs. A
vCPU left idle between wake-ups halts; the next wake-up runs on a cold core (the host may also have moved or
slowed that core meanwhile), and where Linux places each wake-up (beside the busy load generator or on the idle
vCPU) changes from run to run. `bench e2e` measured this on the 2-core VM of round 9: the same Redis run with the
same wake-ups cost 0.38-0.54 s of CPU from run to run, and Redis's CPU per viewer-second followed the load
generator's own CPU share run by run. With the bench and everything it starts on one CPU, three short runs of
each broker agreed within 2-7 % (docs/e2e.md, "How it is measured"; full sittings still move with the VM's own
speed). So `bench e2e` runs on one CPU unless told otherwise; the other suites run where the caller put them.
Affinity is inherited across fork and exec, so setting it on the bench's own process covers every broker,
server and worker it starts.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager

#: what `--cpus` accepts besides a list: every CPU the process may use, or the lowest one of them
ALL, ONE = "all", "one"


class CpuSpecError(ValueError):
    """A `--cpus` value that names no usable CPU; the message says what was asked and what is allowed."""


def allowed() -> set[int] | None:
    """The CPUs this process may run on, or None where the platform cannot say (not Linux)."""
    getter = getattr(os, "sched_getaffinity", None)
    return set(getter(0)) if getter else None


def parse_cpus(text: str, allowed_cpus: set[int]) -> set[int]:
    """`all`, `one` (the lowest allowed CPU) or a list like `0`, `0,2`, `1-3`, within the allowed set."""
    spec = text.strip().lower()
    if not allowed_cpus:
        raise CpuSpecError("this process may run on no CPU at all")
    if spec == ALL:
        return set(allowed_cpus)
    if spec == ONE:
        return {min(allowed_cpus)}
    chosen: set[int] = set()
    for part in spec.split(","):
        lo, sep, hi = part.strip().partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise CpuSpecError(f"--cpus {text!r}: expected 'all', 'one' or CPU numbers like 0,2 or 1-3") from None
        if a < 0 or b < a or b - a > 4096:
            raise CpuSpecError(f"--cpus {text!r}: {part.strip()!r} is not a range of CPU numbers")
        chosen.update(range(a, b + 1))
    outside = sorted(chosen - allowed_cpus)
    if outside:
        raise CpuSpecError(f"--cpus {text!r}: CPU {outside[0]} is not one this process may use "
                           f"(allowed: {_span(allowed_cpus)})")
    return chosen


def _span(cpus: set[int]) -> str:
    return ",".join(str(c) for c in sorted(cpus))


def pin(text: str | None, default: str) -> dict:
    """Run this process (and what it starts from now on) on the CPUs `text` names, `default` when None; the
    report's record of it: the CPUs asked, the ones used, and why not where the platform cannot pin."""
    spec = default if text is None else text
    cpus = allowed()
    if cpus is None:
        return {"cpus_asked": spec, "cpus": None, "pinned": False, "why": "this platform sets no CPU affinity"}
    chosen = parse_cpus(spec, cpus)
    if chosen != cpus:
        _set_every_thread(chosen)
    return {"cpus_asked": spec, "cpus": sorted(chosen), "pinned": chosen != cpus}


@contextmanager
def pinned(text: str | None, default: str) -> Iterator[dict]:
    """`pin` for the length of a `with` block, then every thread back where it was allowed before (a suite run
    in-process, as the tests do, must not leave the caller on one CPU)."""
    before = allowed()
    placement = pin(text, default)
    try:
        yield placement
    finally:
        if before is not None and placement["pinned"]:
            _set_every_thread(before)


def _set_every_thread(cpus: set[int]) -> None:
    """Linux's affinity is per thread: set it on every thread of the process (a library's idle pool included),
    so that no thread, and nothing a thread starts later, runs outside `cpus`."""
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except ProcessLookupError:  # a thread that ended meanwhile
            pass
