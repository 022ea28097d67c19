"""Walks inside areas (squares, parks, pedestrian zones): waypoints instead of edges.

Why separate from the network walks: inside an area a pedestrian is not on any edge (the client core places
it by the area node and x, y), so its truth is a 2D path: straight legs between random waypoints that stay
inside the area's ring, with pauses.
"""

from __future__ import annotations

import math
import random

import numpy as np


def point_in_ring(ring: np.ndarray, x: float, y: float) -> bool:
    """Whether (x, y) is inside the closed ring (even-odd rule, vectorised over the ring's segments)."""
    x0, y0, x1, y1 = ring[:-1, 0], ring[:-1, 1], ring[1:, 0], ring[1:, 1]
    cond = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return bool(np.count_nonzero(cond & (x < xs)) % 2)


def area_walk(ring: np.ndarray, rng: random.Random, duration: float, *, speed: float = 1.3,
              dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(t, xy) every `dt` of a walk between random waypoints inside the ring for about `duration` seconds:
    straight legs that stay inside (checked every 2 m), a quarter of the time a 5-20 s pause instead."""
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
