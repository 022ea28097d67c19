"""The switch benchmark's saturation ladder: offered loads from the standard one upward, per system, and what
the capacity of each system is.

Why: one offered load that every system carries whole says nothing about capacity (each delivers what is
offered, so the ratio is 1.0). The ladder raises the load (more entities over the same viewers) until a system
no longer delivers what is offered, or its latency runs away, and reports per step and system the useful
deliveries/s against the offered ones, p50/p99 latency, server CPU per million deliveries and duplicates.

- *offered* deliveries: for every update the publisher sends inside the window, the number of viewers
  subscribed to at least one of its cells (`OfferedCounter`), i.e. what an ideal switch delivers once each;
- a step is *whole* when at least `WHOLE_SHARE` of the offered deliveries arrived (the rest may be in flight at
  the window's edges, or an older state a switch legitimately replaced by a newer one);
- `capacity_deliveries_per_s`: the highest useful deliveries/s of a whole step with p99 under `P99_LIMIT_MS`;
  `max_deliveries_per_s`: the highest at any latency;
- a system that qualifies at no step from the standard load upward descends `DOWN_STEPS` until one does (a
  busy or small machine: the capacity is then below the standard load, and the report shows it);
- a system stops climbing once a step is past saturation (`past_saturation`): less than `STOP_SHARE` delivered,
  or p99 over `STOP_P99_MS`; further steps would only measure its backlog;
- the steps double, so on their own they tell capacities apart only by factors of two (a ratio could come out
  only 0.5, 1 or 2). `refinements` then bisects each system's bracket (its best qualifying step and the
  lowest failing one above it) geometrically, `REFINE_ROUNDS` times: with two rounds a capacity is known to
  within a factor of 2^(1/4) = 1.19.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

WHOLE_SHARE = 0.95
P99_LIMIT_MS = 100.0
STOP_SHARE = 0.8
STOP_P99_MS = 2000.0

FULL_STEPS = ((5000, 1000), (10_000, 1000), (20_000, 1000), (40_000, 1000), (80_000, 1000))
QUICK_STEPS = ((2000, 300),)
# below the standard load, tried (in this order) only for a system that met the capacity rule at no step above:
# on a machine that cannot carry the standard load at p99 under the limit, the capacity is still measured
DOWN_STEPS = ((2500, 1000), (1250, 1000), (625, 1000))
REFINE_ROUNDS = 2
REFINE_MIN_RATIO = 1.1  # a bracket narrower than this is not split further


class OfferedCounter:
    """How many viewers an update of given cells reaches once each (the union of the cells' subscribers),
    memoised per cells tuple: the publisher asks it for every update it sends, so it must cost a dict lookup."""

    def __init__(self, view_cells: Sequence[Sequence[int]], n_cells: int):
        m = np.zeros((n_cells, len(view_cells)), dtype=bool)
        for v, cells in enumerate(view_cells):
            m[list(cells), v] = True
        self._m = m
        self._memo: dict[tuple[int, ...], int] = {}

    def __call__(self, cells: Sequence[int]) -> int:
        key = tuple(cells)
        n = self._memo.get(key)
        if n is None:
            n = int(np.logical_or.reduce(self._m[list(key)], axis=0).sum()) if key else 0
            self._memo[key] = n
        return n


def whole(step: dict[str, Any]) -> bool:
    """The step's useful deliveries are at least `WHOLE_SHARE` of what was offered."""
    offered = step.get("offered_deliveries_per_s") or 0.0
    return offered > 0 and step["deliveries_per_s"] >= WHOLE_SHARE * offered


def within_latency(step: dict[str, Any]) -> bool:
    """p99 under `P99_LIMIT_MS` (a step without any delivery is not)."""
    p99 = step.get("latency_p99_ms")
    return p99 is not None and p99 < P99_LIMIT_MS


def past_saturation(step: dict[str, Any]) -> bool:
    """Climbing further is pointless: far less delivered than offered, or latency is a backlog."""
    offered = step.get("offered_deliveries_per_s") or 0.0
    p99 = step.get("latency_p99_ms")
    return (offered > 0 and step["deliveries_per_s"] < STOP_SHARE * offered) or p99 is None or p99 > STOP_P99_MS


def capacity(steps: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Capacity (highest whole step with p99 under the limit), the maximum at any latency, and which steps."""
    ok = [s for s in steps if qualifies(s)]
    best = max(ok, key=lambda s: s["deliveries_per_s"], default=None)
    top = max(steps, key=lambda s: s["deliveries_per_s"], default=None)
    return {
        "capacity_deliveries_per_s": best["deliveries_per_s"] if best else None,
        "capacity_step": [best["entities"], best["viewers"]] if best else None,
        "max_deliveries_per_s": top["deliveries_per_s"] if top else None,
        "max_step": [top["entities"], top["viewers"]] if top else None,
    }


def ratio(a: float | None, b: float | None) -> float | None:
    """a / b, None when either is unknown (a system that did not run, or no step within the latency limit)."""
    if a is None or not b:
        return None
    return a / b


STEP_KEYS = ("entities", "viewers", "offered_deliveries_per_s", "deliveries_per_s", "duplicates_per_s",
             "latency_p50_ms", "latency_p99_ms", "cpu_s_per_million_deliveries", "server_cpu_s",
             "server_cpu_cores", "machine_busy_cores", "updates_in_per_s", "loadgen_max_tick_lateness_ms")


def qualifies(step: dict[str, Any]) -> bool:
    """The step counts as capacity: whole and p99 under the limit."""
    return whole(step) and within_latency(step)


def bracket(steps: Sequence[dict[str, Any]]) -> tuple[int, int] | None:
    """(entities of the best qualifying step, entities of the lowest step above it that does not qualify), the
    interval where the system's capacity lies; None when it has no such interval (nothing qualified, or nothing
    above the best failed). Steps over other viewer counts than the best one's are not compared."""
    ok = [s for s in steps if qualifies(s)]
    if not ok:
        return None
    best = max(ok, key=lambda s: s["deliveries_per_s"])
    above = [s["entities"] for s in steps
             if s["viewers"] == best["viewers"] and s["entities"] > best["entities"] and not qualifies(s)]
    return (best["entities"], min(above)) if above else None


def refinements(ladder: dict[str, Sequence[dict[str, Any]]]) -> dict[str, int]:
    """The next step (entities) to run per system: the geometric middle of its bracket, rounded to tens;
    systems whose bracket is unknown or already narrower than `REFINE_MIN_RATIO` get none."""
    out = {}
    for system, steps in ladder.items():
        b = bracket(steps)
        if b is not None and b[1] / b[0] > REFINE_MIN_RATIO:
            out[system] = int(round((b[0] * b[1]) ** 0.5, -1))
    return out


def step_row(entities: int, viewers: int, res: dict[str, Any]) -> dict[str, Any]:
    """The figures of one step for the report (and the verdicts)."""
    row = {"entities": entities, "viewers": viewers, **{k: res.get(k) for k in STEP_KEYS[2:]}}
    row["whole"] = whole(row)
    row["p99_under_limit"] = within_latency(row)
    return row
