"""The benchmark output contract of DESIGN.md: one JSON object per run."""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def machine() -> dict[str, Any]:
    """The report's `machine` block, so that figures from different hosts are not compared blindly."""
    return {
        "cores": os.cpu_count(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "processor": platform.machine(),
    }


def write_report(suite: str, body: dict[str, Any], out: str | os.PathLike | None) -> dict[str, Any]:
    """The report object of DESIGN.md's contract (suite, machine, params, results; peer, ratio and notes
    when given), written as JSON to `out` when it is set."""
    report = {
        "suite": suite,
        "machine": machine(),
        "params": body.get("params", {}),
        "results": body["results"],
    }
    for key in ("peer", "ratio", "notes", "ladder"):
        if key in body:
            report[key] = body[key]
    text = json.dumps(report, indent=2, sort_keys=False, default=float)
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(text + "\n")
    return report


def print_json(report: dict[str, Any], out: str | os.PathLike | None) -> None:
    """A diagnostic run's JSON (`python -m sims.bench.sim_causes`, `dr_causes`): printed, and written to `out`
    when given."""
    text = json.dumps(report, indent=2)
    if out:
        with open(out, "w") as f:
            f.write(text + "\n")
    print(text)


def median_time(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """Median wall time of `repeat` calls of fn, and the last result."""
    times, result = [], None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def pyplot(progress: Callable[[str], Any]):
    """matplotlib's pyplot on the headless Agg backend, or None (with a note through `progress`) when matplotlib
    is not installed: a plot is an extra (the `plot` extra), and the report is written without it."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        progress("matplotlib not installed: no plot")
        return None
    return plt
