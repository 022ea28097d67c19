"""Speed profiles: how far along its path an entity is at each moment, with bounded acceleration.

Why a profile rather than a constant speed: dead reckoning is judged by how it copes with starts, stops and
speed changes, so a benchmark's truth must accelerate, brake for stops and red signals, and drift around its
cruise speed the way vehicles and walkers do. Profiles are sampled at a fixed step and deterministic for a
given `random.Random`.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import numpy as np

from sims.mobility.kinds import Halts, Kind


@dataclass(frozen=True)
class Profile:
    """Distance along the path (`s`, metres) at regular times (`t`, seconds from the start)."""

    t: np.ndarray
    s: np.ndarray


def speed_profile(length: float, halts: list[tuple[float, float]], rng: random.Random, *, cruise: float,
                  accel: float, decel: float, dt: float = 0.1, vary: float = 0.15,
                  t_max: float = 4 * 3600.0) -> Profile:
    """Motion along [0, length]: `halts` are (position, dwell seconds), sorted; braking is planned with
    `decel` so that every halt is reached at zero speed; the cruise speed drifts by +-`vary` every 10-20 s."""
    halts = sorted((p, w) for p, w in halts if 0.0 < p < length)
    s, v, t = 0.0, 0.0, 0.0
    ts, ss = [0.0], [0.0]
    hi = 0
    target = cruise
    next_vary = rng.uniform(10.0, 20.0)
    dwell_left = 0.0
    while s < length - 1e-6 and t < t_max:
        if t >= next_vary:
            target = cruise * rng.uniform(1.0 - vary, 1.0 + vary * 0.5)
            next_vary = t + rng.uniform(10.0, 20.0)
        if dwell_left > 0.0:
            dwell_left -= dt
            v = 0.0
        else:
            stop_at = halts[hi][0] if hi < len(halts) else length
            d = stop_at - s
            if d <= 0.05 and v <= decel * dt * 1.5:
                s = max(s, stop_at) if hi < len(halts) else s
                v = 0.0
                if hi < len(halts):
                    dwell_left = halts[hi][1]
                    hi += 1
                else:
                    break
            else:
                v_allow = math.sqrt(max(2.0 * decel * max(d, 0.0), 0.0))
                vt = min(target, v_allow)
                if v < vt:
                    v = min(v + accel * dt, vt)
                else:
                    v = max(v - 1.5 * decel * dt, vt, 0.0)
                s = min(s + v * dt, stop_at if hi < len(halts) else length)
        t += dt
        ts.append(t)
        ss.append(s)
    return Profile(np.array(ts), np.array(ss))


def vehicle_halts(stops: list[float], signals: list[float], rng: random.Random,
                  halts: Halts) -> list[tuple[float, float]]:
    """(position, seconds) of a scheduled vehicle's halts: every stop (a dwell) and each signal that happens
    to be red; halts closer than 15 m merge into one (the longer wait), since a vehicle does not stop twice
    within its own length."""
    out = [(p, rng.uniform(*halts.dwell)) for p in stops]
    out += [(p, rng.uniform(*halts.red)) for p in signals if rng.random() < halts.p_red]
    out.sort()
    merged: list[tuple[float, float]] = []
    for p, w in out:
        if merged and p - merged[-1][0] < 15.0:
            merged[-1] = (merged[-1][0], max(merged[-1][1], w))
        else:
            merged.append((p, w))
    return merged


def profile_for(k: Kind, length: float, halts: list[tuple[float, float]], rng: random.Random) -> Profile:
    """`speed_profile` with the kind's cruise, acceleration, braking and drift: the one place that turns a
    kind into motion along a path, so every run moves a tram the same way."""
    if k.accel is None or k.decel is None:
        raise ValueError(f"kind {k.name!r} has no acceleration bounds for a speed profile")
    return speed_profile(length, halts, rng, cruise=k.cruise, accel=k.accel, decel=k.decel, vary=k.vary)
