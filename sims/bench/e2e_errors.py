"""`python -m sims.bench.e2e_errors`: the viewer position error's distribution per system, from one run each.

Why: `bench e2e` reports the error's mean, p95 and max, and the issue's target compares p95s (ours against
MQTT at 1 Hz). What sets a p95 is the shape under it: a bounded drift (dead reckoning's threshold, the GPS
noise) or the age of the last fix (a 1 Hz position shown until the next one). This runs the chosen systems once
each with `e2e_short`'s workload and prints, per system and viewer group, the error's quantiles and a histogram
in metres (the same samples `sims.engine.measure` summarises; it keeps them, this only reads them). A
diagnostic: it changes nothing that the bench measures.

    python -m sims.bench.e2e_errors --systems entitynet,mqtt-disc --seconds 40
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
from typing import Any

import numpy as np

QUANTILES = (50, 75, 90, 95, 99)
EDGES_M = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 12, 15, 20, 30, 50, math.inf)  # the last bin takes the rest


def distribution(errors: list[float]) -> dict[str, Any]:
    """Quantiles and a histogram (fractions per bin of EDGES_M) of one group's errors."""
    e = np.asarray(errors, dtype=float)
    if not e.size:
        return {"samples": 0}
    hist, _ = np.histogram(np.minimum(e, EDGES_M[-2]), bins=EDGES_M[:-1] + (EDGES_M[-2] + 1,))
    return {"samples": int(e.size), **{f"p{q}_m": round(float(np.percentile(e, q)), 3) for q in QUANTILES},
            "max_m": round(float(e.max()), 3),
            "histogram": {f"{EDGES_M[i]:g}-{EDGES_M[i + 1]:g}": round(int(h) / e.size, 4)
                          for i, h in enumerate(hist)}}


def main(argv: list[str] | None = None) -> int:
    """Run each system once (e2e_short's workload) and print the error distributions as JSON."""
    from sims.bench import e2e_short
    from sims.engine import measure

    ap = argparse.ArgumentParser(prog="python -m sims.bench.e2e_errors", description=__doc__.split("\n\n")[0])
    ap.add_argument("--systems", default="entitynet,mqtt-disc")
    ap.add_argument("--seconds", type=float, default=40.0)
    a = ap.parse_args(argv)
    kept: list[dict[str, list[float]]] = []
    summary = measure.Measure.summary

    def keeping(self: measure.Measure) -> dict:
        kept.append({k: list(t.errors) for k, t in self.tallies.items()})
        return summary(self)

    measure.Measure.summary = keeping  # type: ignore[method-assign]  # read the samples, change nothing
    try:
        out: dict[str, Any] = {}
        for name in a.systems.split(","):
            before = len(kept)
            with contextlib.redirect_stdout(sys.stderr):  # e2e_short's own figures go with the progress
                rc = e2e_short.main(["--systems", name, "--seconds", str(a.seconds), "--reps", "1"])
            if rc or len(kept) == before:
                print(f"e2e_errors: {name} did not run", file=sys.stderr)
                return rc or 1
            groups = kept[-1]
            out[name] = {g: distribution(v) for g, v in sorted(groups.items())}
            out[name]["all"] = distribution([x for v in groups.values() for x in v])
    finally:
        measure.Measure.summary = summary  # type: ignore[method-assign]
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
