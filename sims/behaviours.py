"""Entity behaviours for simulations and benchmarks: realistic 1D speed profiles, walks, GPS noise.

- `speed_profile`: a vehicle or walker along a path of known length: accelerates, cruises with slow speed
  variation, brakes for stops (dwell) and for signals that happen to be red, all with bounded acceleration.
- `random_walk`: a pedestrian's path on the walkway network (random turn at every junction, no U-turns).
- `area_walk`: a pedestrian walking between random waypoints inside an area, pausing now and then.
- `gps`: fixes at 1 Hz with Gaussian noise (horizontal RMS `sigma` metres).
Everything is deterministic for a given `random.Random`.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import numpy as np

from entitynet.client.network import DirEdge, NetView


@dataclass(frozen=True)
class Profile:
    t: np.ndarray  # seconds, regular steps
    s: np.ndarray  # metres along the path


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


def vehicle_halts(stops: list[float], signals: list[float], rng: random.Random, *, dwell: tuple[float, float],
                  p_red: float, red: tuple[float, float]) -> list[tuple[float, float]]:
    """Stops (always, dwell) and signals (red with probability p_red, wait) as (position, seconds)."""
    out = [(p, rng.uniform(*dwell)) for p in stops]
    out += [(p, rng.uniform(*red)) for p in signals if rng.random() < p_red]
    out.sort()
    merged: list[tuple[float, float]] = []
    for p, w in out:
        if merged and p - merged[-1][0] < 15.0:
            merged[-1] = (merged[-1][0], max(merged[-1][1], w))
        else:
            merged.append((p, w))
    return merged


def random_walk(net: NetView, start: DirEdge, networks: int, length: float, rng: random.Random) -> list[DirEdge]:
    """A random path of about `length` metres; stops early at dead ends and area nodes."""
    edges = [start]
    total = net.edge_len[start[0]]
    while total < length and len(edges) < 500:
        ch = [c for c in net.choices(edges[-1], networks) if net.node_area[net.end_node(edges[-1])] < 0]
        if not ch:
            break
        nxt = ch[rng.randrange(len(ch))]
        edges.append(nxt)
        total += net.edge_len[nxt[0]]
    return edges


def point_in_ring(ring: np.ndarray, x: float, y: float) -> bool:
    x0, y0, x1, y1 = ring[:-1, 0], ring[:-1, 1], ring[1:, 0], ring[1:, 1]
    cond = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return bool(np.count_nonzero(cond & (x < xs)) % 2)


def area_walk(ring: np.ndarray, rng: random.Random, duration: float, *, speed: float = 1.3,
              dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(t, xy) of a walk between random waypoints inside the ring (straight legs that stay inside)."""
    x0, y0 = ring.min(axis=0)
    x1, y1 = ring.max(axis=0)

    def sample() -> tuple[float, float]:
        for _ in range(1000):
            p = (rng.uniform(x0, x1), rng.uniform(y0, y1))
            if point_in_ring(ring, *p):
                return p
        return float(ring[0, 0]), float(ring[0, 1])

    pos = sample()
    ts, xy = [0.0], [pos]
    t = 0.0
    while t < duration:
        if rng.random() < 0.25:  # pause
            for _ in range(int(rng.uniform(5.0, 20.0) / dt)):
                t += dt
                ts.append(t)
                xy.append(pos)
            continue
        for _ in range(20):
            goal = sample()
            n = max(int(math.dist(pos, goal) / 2.0), 1)
            if all(point_in_ring(ring, pos[0] + (goal[0] - pos[0]) * k / n, pos[1] + (goal[1] - pos[1]) * k / n)
                   for k in range(n + 1)):
                break
        else:
            goal = pos
        v = speed * rng.uniform(0.8, 1.2)
        steps = max(int(math.dist(pos, goal) / (v * dt)), 1)
        for k in range(1, steps + 1):
            t += dt
            ts.append(t)
            xy.append((pos[0] + (goal[0] - pos[0]) * k / steps, pos[1] + (goal[1] - pos[1]) * k / steps))
        pos = goal
    return np.array(ts), np.array(xy)


def gps(xy: np.ndarray, rng: np.random.Generator, sigma: float = 5.0) -> np.ndarray:
    """Noisy fixes: independent Gaussian errors per axis of sigma/sqrt(2), i.e. horizontal RMS `sigma`."""
    return xy + rng.normal(0.0, sigma / math.sqrt(2.0), size=xy.shape)
