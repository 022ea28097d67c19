"""Extrapolation limits: how far and how fast any dead-reckoning model may carry an entity.

A published model is a promise about the next seconds, not about the next hours. Without limits a player
whose fixes stopped re-published its own guess on every validity expiry forever, and a second-order (FVW)
guess accelerated without bound: after a 208 s gap 21 km off at 174 m/s, after 2.6 h 38,000 km. So:
- every model, on every receiver and in the player alike, extrapolates at most `HORIZON` seconds past its
  own t0 and then stands still; its speed never exceeds its entity type's `max_speed` (unknown type codes
  from the wire get `MAX_SPEED`);
- the player (entitynet/client/player.py) stops extrapolating `max_gap` seconds after its last fix and
  publishes a standing model there, and unpublishes the entity `lost_after` seconds after its last fix
  (per type, entitynet/client/entities.py).

HORIZON is longer than the player's default heartbeat and validity cap (60 s), so a player that has fixes
re-publishes before any of its models reach it: traces without gaps extrapolate exactly as before.
"""

from __future__ import annotations

import math

from entitynet.client.entities import BY_CODE

HORIZON = 90.0  # s: no model extrapolates further past its t0
MAX_SPEED = max(t.max_speed for t in BY_CODE.values())  # m/s: the cap for a type code this build does not know
_SPEED = {code: t.max_speed for code, t in BY_CODE.items()}


def max_speed(etype: int) -> float:
    """The speed no extrapolation of this entity type code exceeds (m/s)."""
    return _SPEED.get(etype, MAX_SPEED)


def horizon_dt(dt: float) -> float:
    """Seconds of extrapolation after t0 that a model actually applies: none backwards, none past HORIZON."""
    if dt <= 0.0:
        return 0.0
    return dt if dt < HORIZON else HORIZON


def capped_velocity(vx: float, vy: float, cap: float) -> tuple[float, float]:
    """(vx, vy) scaled down to magnitude `cap` when faster (a constant-velocity model's speed limit)."""
    speed = math.hypot(vx, vy)
    if speed <= cap:
        return vx, vy
    f = cap / speed
    return vx * f, vy * f


def world_state(vx: float, vy: float, ax: float, ay: float, cap: float,
                dt: float) -> tuple[float, float, float, float]:
    """(dx, dy, vx, vy) after `dt` seconds (already limited by `horizon_dt`) of constant acceleration with the
    speed capped at `cap`: the acceleration applies until the speed reaches the cap, then the velocity holds.

    The moment of reaching the cap is the positive root of |v + a t| = cap, computed as
    t = (-(v.a) + sqrt((v.a)^2 - |a|^2 (|v|^2 - cap^2))) / |a|^2; a start already above the cap is scaled to it."""
    a2 = ax * ax + ay * ay
    v2 = vx * vx + vy * vy
    if v2 > cap * cap:
        vx, vy = capped_velocity(vx, vy, cap)
        return vx * dt, vy * dt, vx, vy
    if a2 == 0.0:
        return vx * dt, vy * dt, vx, vy
    va = vx * ax + vy * ay
    t_cap = (-va + math.sqrt(max(va * va - a2 * (v2 - cap * cap), 0.0))) / a2
    if dt <= t_cap:
        h = 0.5 * dt * dt
        return vx * dt + ax * h, vy * dt + ay * h, vx + ax * dt, vy + ay * dt
    h = 0.5 * t_cap * t_cap
    wx, wy = vx + ax * t_cap, vy + ay * t_cap
    rest = dt - t_cap
    return vx * t_cap + ax * h + wx * rest, vy * t_cap + ay * h + wy * rest, wx, wy
