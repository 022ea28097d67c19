"""The free walkers' step over arrays: every entity with nothing to react to, moved in one numpy pass.

Why: most of a large run's entities are pedestrians, and a pedestrian (no body length, no stops) reacts to
nothing: its step is IDM on a free road, `behaviour.idm` with no obstacle. `World.step` used to visit each in a
Python loop (about 2.5 us an entity-tick of the world's 7.6 at 3,000 entities); here their state lives in
columns (s, v, v0, accel, decel, the route's length, distance) and the step is a handful of array operations,
then one pass writes s, v and distance back to the `Agent` objects that the fleet and the measure read.

Same truth, bit for bit: every operation is the scalar one in the same order (IEEE +, -, *, / give the same
double in numpy as in Python), `max(x, 0.0)` is written as the `np.where` that returns what Python's `max`
returns (its first argument unless the second is greater, so the sign of a zero is kept), and the one
operation whose last bit could differ, IDM's `(v / v0) ** 4` (numpy's `power` may take a SIMD path where
Python calls the C library's `pow`), is taken from Python's own `**` for every ratio other than exactly 0 or 1
(a walker at its desired speed has ratio 1: most of them, most of the time). tests/sims/engine/test_free_flow.py
runs worlds both ways and compares every entity's state after every step.

An entity is a free walker from its spawn while it avoids nothing (`params.avoids` false) and has no stops;
it leaves the columns for `World`'s scalar step when it is stalled, reaches its route's end (the area walk or
its removal are the scalar step's) or is removed.
"""

from __future__ import annotations

import numpy as np

from sims.engine.agents import Agent


def _py_max0(x: np.ndarray) -> np.ndarray:
    """Python's `max(x, 0.0)` elementwise: x unless 0.0 > x (so -0.0 stays -0.0, as `max` returns it)."""
    return np.where(0.0 > x, 0.0, x)


def _py_max0_first(x: np.ndarray) -> np.ndarray:
    """Python's `max(0.0, x)` elementwise: 0.0 unless x > 0.0."""
    return np.where(x > 0.0, x, 0.0)


class FreeFlow:
    """Columns of the free walkers; `step(dt)` moves them all and returns those that reached their route's end."""

    def __init__(self) -> None:
        self.agents: list[Agent] = []
        self.row: dict[int, int] = {}  # entity id -> its row
        self.s = np.zeros(0)
        self.v = np.zeros(0)
        self.v0 = np.zeros(0)
        self.accel = np.zeros(0)
        self.decel = np.zeros(0)
        self.end = np.zeros(0)  # where the route's end counts as reached: length - 1e-6 (the scalar test)
        self.dist = np.zeros(0)
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def __contains__(self, aid: int) -> bool:
        return aid in self.row

    @staticmethod
    def takes(a: Agent) -> bool:
        """Whether an entity moves on a free road for now: it avoids nothing, has no stop to serve, stands in
        no area and is not stalled (the step's `_decide` would give it IDM with no obstacle)."""
        return (not a.params.avoids and a.next_stop >= len(a.stops) and a.in_area_since is None
                and a.stalled_until < 0.0 and a.dwell_until is None)

    def add(self, a: Agent) -> None:
        """Take an entity's state into the columns (it must be `takes`-able)."""
        n = self._n
        if n == len(self.s):
            grow = max(64, n)
            for name in ("s", "v", "v0", "accel", "decel", "end", "dist"):
                setattr(self, name, np.concatenate([getattr(self, name), np.zeros(grow)]))
        p = a.params
        self.s[n], self.v[n], self.v0[n] = a.s, a.v, a.v_free
        self.accel[n], self.decel[n] = p.accel, p.decel
        self.end[n] = a.route.length - 1e-6
        self.dist[n] = a.distance
        self.agents.append(a)
        self.row[a.id] = n
        self._n = n + 1

    def drop(self, aid: int) -> None:
        """Let an entity go (to the scalar step, or out of the world): its row takes the last row's entity."""
        k = self.row.pop(aid, None)
        if k is None:
            return
        last = self._n - 1
        if k != last:
            moved = self.agents[last]
            self.agents[k] = moved
            self.row[moved.id] = k
            for col in (self.s, self.v, self.v0, self.accel, self.decel, self.end, self.dist):
                col[k] = col[last]
        self.agents.pop()
        self._n = last

    def step(self, dt: float, now: float) -> list[Agent]:
        """Move every free walker by `dt` (IDM with no obstacle, as `World._decide` does), write s, v, distance
        and the clock back to the agents, and return those at their route's end, for the scalar `_after_move`."""
        n = self._n
        if n == 0:
            return []
        s, v, v0 = self.s[:n], self.v[:n], self.v0[:n]
        a, b = self.accel[:n], self.decel[:n]
        # behaviour.idm with gap = inf: v0 <= 0 stands (braking at b while it moves), else a * (1 - (v/v0)^4)
        going = v0 > 0.0
        ratio = _py_max0(v) / np.where(going, v0, 1.0)
        power = ratio.copy()  # exact for ratio 0 and 1 (and -0.0: 1 - -0.0 == 1 - 0.0)
        odd = np.flatnonzero((ratio != 1.0) & (ratio != 0.0))
        if len(odd):
            power[odd] = [r**4 for r in ratio[odd].tolist()]  # Python's pow, as the scalar step
        acc = np.where(going, a * (1.0 - power), np.where(v > 0, -b, 0.0))
        new_v = _py_max0_first(v + acc * dt)
        halts = (acc < 0) & (v > 0) & (new_v == 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            ds = np.where(halts, v * v / (-2.0 * acc), 0.5 * (v + new_v) * dt)
        new_s = s + _py_max0(ds)
        self.dist[:n] += _py_max0(new_s - s)
        self.s[:n] = new_s
        self.v[:n] = new_v
        for ag, si, vi, di in zip(self.agents, new_s.tolist(), new_v.tolist(), self.dist[:n].tolist(), strict=True):
            ag.s, ag.v, ag.distance, ag._clock = si, vi, di, now
        ended = np.flatnonzero(new_s >= self.end[:n])
        return [self.agents[k] for k in ended.tolist()]
