"""1D motion with speed, acceleration and a speed cap: distance after a time, and time to cover a distance.

Both directions of the question use the same piecewise model, so a validity period computed by a player is
exactly the moment its published extrapolation reaches the boundary:
- a < 0: decelerate until the speed reaches 0, then stand still (never reverse);
- a > 0: accelerate until `vmax`, then keep `vmax`;
- a = 0 or v = vmax: constant speed.
Every division has a defined result at zero: no motion ahead gives an unbounded time (math.inf).
"""

from __future__ import annotations

import math

INF = math.inf
A_EPS = 1e-9  # accelerations smaller than this (m/s^2) are zero: no underflowing t^2 terms
D_EPS = 1e-9  # distances smaller than this (m) are reached at once: no denormal divisions


def _a(a: float) -> float:
    return 0.0 if -A_EPS < a < A_EPS else a


def advance(v: float, a: float, vmax: float, dt: float) -> tuple[float, float]:
    """(distance, speed) after `dt` >= 0 seconds from speed v >= 0 with acceleration a, speed capped at vmax."""
    if dt <= 0.0:
        return 0.0, v
    a = _a(a)
    if a < 0.0:
        t_stop = v / -a
        if dt >= t_stop:
            return v * t_stop + 0.5 * a * t_stop * t_stop, 0.0
        return v * dt + 0.5 * a * dt * dt, v + a * dt
    if a > 0.0 and v < vmax:
        t_cap = (vmax - v) / a
        if dt <= t_cap:
            return v * dt + 0.5 * a * dt * dt, v + a * dt
        return v * t_cap + 0.5 * a * t_cap * t_cap + vmax * (dt - t_cap), vmax
    return v * dt, v


def time_to_travel(d: float, v: float, a: float, vmax: float) -> float:
    """Earliest t >= 0 at which `advance` has covered distance d; math.inf when it never does.

    Uses t = 2d / (v + sqrt(v^2 + 2ad)), which is stable as a -> 0 and has no cancellation; a negative
    discriminant means the entity stops before d (no real root).
    """
    if not d > D_EPS:
        return 0.0
    a = _a(a)
    if a > 0.0 and v < vmax:
        t_cap = (vmax - v) / a
        d_cap = v * t_cap + 0.5 * a * t_cap * t_cap
        if d > d_cap:
            return t_cap + (d - d_cap) / vmax if vmax > 0.0 else INF
        disc = v * v + 2.0 * a * d
        return 2.0 * d / (v + math.sqrt(disc))
    if a < 0.0:
        disc = v * v + 2.0 * a * d
        if disc < 0.0:
            return INF
        den = v + math.sqrt(disc)
        return 2.0 * d / den if den > 0.0 else INF
    return d / v if v > 0.0 else INF


def brake_plan(v: float, a: float, vmax: float, d: float, b: float) -> tuple[float, float]:
    """When to start braking at `b` (m/s^2) so as to stop exactly `d` metres ahead, given the free motion
    (v, a, vmax) of `advance`: returns (t_brake, deceleration used). t_brake = inf when the free motion
    stops on its own first (or there is nothing ahead); t_brake = 0 with a harder deceleration when the
    stop is already closer than the braking distance.

    Solves (v + a t)^2 = 2 b (d - v t - a t^2 / 2) in the accelerating or decelerating phase, and the linear
    form in the constant-speed phase; the same closed form runs at the player and at every receiver."""
    a = _a(a)
    if not (d > 0.0 and b > 0.0):
        return (0.0, INF) if d <= 0.0 and v > 0.0 else (INF, b)
    if v * v >= 2.0 * b * d:
        return 0.0, (v * v / (2.0 * d)) if v > 0.0 else b
    if a != 0.0 and not (a > 0.0 and v >= vmax):
        t_end = (vmax - v) / a if a > 0.0 else v / -a  # end of the accelerating / decelerating phase
        qa, qb, qc = a * (a + b), 2.0 * v * (a + b), v * v - 2.0 * b * d
        roots = []
        disc = qb * qb - 4.0 * qa * qc
        if disc >= 0.0:
            # the cancellation-free pair of roots (q / qa and qc / q): exact as qa -> 0 too
            q = -0.5 * (qb + math.copysign(math.sqrt(disc), qb))
            if q != 0.0:
                roots.append(qc / q)
            if qa != 0.0:
                roots.append(q / qa)
        ts = [t for t in roots if 0.0 <= t <= t_end]
        if ts:
            return min(ts), b
        if a < 0.0:
            return INF, b  # stops on its own before the braking point
        s_cap = v * t_end + 0.5 * a * t_end * t_end
        v = vmax
        t0, d = t_end, d - s_cap
    else:
        t0 = 0.0
    if v <= 0.0:
        return INF, b
    return t0 + max((d - v * v / (2.0 * b)) / v, 0.0), b
