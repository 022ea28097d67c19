"""The vehicles' (and stop-serving walkers') move over arrays: IDM over their obstacles, the integration and the
hard limits, for every entity of the scalar step at once, once each one's obstacles are known.

Why: after the free walkers (`free_flow`) and the leaders (`leaders`), the largest per-entity cost of
`World.step` was `behaviour.accel_for` (one `idm` call for the free road and one per obstacle) and the move
after it. The obstacles themselves stay found per entity (the stop ahead, the leader found over arrays, the
junction requests in id order: they are order-dependent); what they ask of the entity is computed here for all.

Same truth, bit for bit, as `accel_for` and `World._finish`: an entity's obstacles are its columns 0, 1, 2 in
the order of its list (stop, leader, crossing), each taken when it brakes harder by more than 1e-9 than the best
so far (as the scalar loop); every IEEE operation is the scalar one in the same order; Python's `max(x, y)`
(x unless y > x) is written as the `np.where` that keeps a zero's sign; `(v / v0) ** 4` and `(s* / gap) ** 2`
are Python's own `**` (the C library's `pow`, whose last bit numpy's `power` or `x * x` need not share), except
for ratios exactly 0 or 1. tests/sims/engine/test_free_flow.py compares the worlds after every step.
"""

from __future__ import annotations

import numpy as np

from sims.engine.agents import Agent
from sims.engine.behaviour import EMERGENCY, Obstacle

#: at most this many obstacles per entity (the stop ahead, the leader, the crossing)
MAX_OBSTACLES = 3


def _py_max(x: np.ndarray, y: np.ndarray | float) -> np.ndarray:
    """Python's `max(x, y)` elementwise: x unless y > x (a zero's sign and a NaN kept as `max` keeps them)."""
    return np.where(y > x, y, x)


def _py_pow(x: np.ndarray, k: int) -> np.ndarray:
    """`x ** k` by Python's float `**` for every element other than exactly 0 or 1 (exact as they are)."""
    out = x.copy()
    odd = np.flatnonzero((x != 1.0) & (x != 0.0))
    if len(odd):
        out[odd] = [r**k for r in x[odd].tolist()]
    return out


def moves(agents: list[Agent], obstacles: list[list[Obstacle]], dt: float
          ) -> tuple[list[float], list[float], list[Obstacle | None]]:
    """Each agent's new (s, v) after `dt` and the obstacle that limits it (None on a free road), as
    `World._finish` computes them before a stop is served: `accel_for`, the integration, never into a
    non-stop obstacle (0.3 m short of it, standing)."""
    n = len(agents)
    if n == 0:
        return [], [], []
    if any(len(obs) > MAX_OBSTACLES for obs in obstacles):
        raise ValueError(f"at most {MAX_OBSTACLES} obstacles per entity")
    s = np.array([a.s for a in agents], dtype=float)
    v = np.array([a.v for a in agents], dtype=float)
    v0 = np.array([a.v0 for a in agents], dtype=float)
    ps = [a.params for a in agents]
    acc_max = np.array([p.accel for p in ps], dtype=float)
    dec = np.array([p.decel for p in ps], dtype=float)
    headway = np.array([p.headway for p in ps], dtype=float)
    gap0 = np.array([p.gap for p in ps], dtype=float)

    going = v0 > 0.0
    stand = np.where(v > 0, -dec, 0.0)  # behaviour.idm with v0 <= 0, whatever is ahead
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(going, _py_max(v, 0.0) / np.where(going, v0, 1.0), 0.0)
        free = acc_max * (1.0 - _py_pow(ratio, 4))
        best = np.where(going, free, stand)
        limit = np.full(n, -1)
        root = 2.0 * np.sqrt(acc_max * dec)
        for j in range(MAX_OBSTACLES):
            rows = np.array([i for i, obs in enumerate(obstacles) if len(obs) > j], dtype=np.intp)
            if len(rows) == 0:
                break
            obs_j = [obstacles[i][j] for i in rows.tolist()]
            at = np.array([ob.at for ob in obs_j], dtype=float)
            speed = np.array([ob.speed for ob in obs_j], dtype=float)
            s0 = np.array([np.nan if ob.s0 is None else ob.s0 for ob in obs_j], dtype=float)
            hw = np.array([np.nan if ob.headway is None else ob.headway for ob in obs_j], dtype=float)
            s0 = np.where(np.isnan(s0), gap0[rows], s0)
            hw = np.where(np.isnan(hw), headway[rows], hw)
            vr = v[rows]
            gap = at - s[rows]
            dv = vr - speed
            s_star = s0 + _py_max(0.0, vr * hw + vr * dv / root[rows])
            q = s_star / np.where(gap > 1e-6, gap, 1.0)
            acc = _py_max(free[rows] - acc_max[rows] * _py_pow(np.where(gap > 1e-6, q, 0.0), 2), -EMERGENCY)
            acc = np.where(gap <= 1e-6, -EMERGENCY, acc)
            acc = np.where(going[rows], acc, stand[rows])
            take = acc < best[rows] - 1e-9
            best[rows] = np.where(take, acc, best[rows])
            limit[rows] = np.where(take, j, limit[rows])

        new_v = _py_max(0.0, v + best * dt)
        halts = (best < 0) & (v > 0) & (new_v == 0.0)
        ds = np.where(halts, v * v / (-2.0 * best), 0.5 * (v + new_v) * dt)
    new_s = s + _py_max(ds, 0.0)
    limits: list[Obstacle | None] = [None if k < 0 else obstacles[i][k] for i, k in enumerate(limit.tolist())]
    hard_rows = [i for i, ob in enumerate(limits) if ob is not None and ob.kind != "stop"]
    if hard_rows:  # never into the obstacle
        r = np.array(hard_rows, dtype=np.intp)
        hard = _py_max(np.array([limits[i].at for i in hard_rows], dtype=float) - 0.3, s[r])
        over = new_s[r] > hard
        new_s[r] = np.where(over, hard, new_s[r])
        new_v[r] = np.where(over, 0.0, new_v[r])
    return new_s.tolist(), new_v.tolist(), limits
