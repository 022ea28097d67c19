"""Dead-reckoning models: what a player publishes and every receiver extrapolates, with the same code.

- `NetworkModel`: path-constrained; the front at path coordinate s0 at time t0 moves with speed v >= 0 and
  acceleration a (stopping at zero speed, capped at vmax) along an explicit list of directed edges (the
  a-priori route, or the junction rule of `NetView.next_edge`, resolved by the player and published). It
  clamps at the end of its path.
- `AreaModel`: 2D constant velocity inside an area node (pedestrians on squares, cars on parking lots).
- `WorldModel`: the DIS baselines in the world frame: FPW (first order: position + velocity), FVW (second
  order: + acceleration), and the zero-order hold used by periodic updates (velocity 0).

All models answer `xy_at(t)`; `t < t0` answers the state at t0 (receivers never extrapolate backwards).
"""

from __future__ import annotations

from dataclasses import dataclass

from entitynet.client.kinematics import advance
from entitynet.client.path import Path

KIND_NETWORK, KIND_AREA, KIND_WORLD = 1, 2, 3


@dataclass(frozen=True, slots=True)
class NetworkModel:
    t0: float
    path: Path
    s0: float
    v: float
    a: float
    vmax: float
    etype: int
    parts: tuple[float, ...]  # body part lengths from the front (two entries for a two-part tram)

    kind = KIND_NETWORK

    @property
    def length(self) -> float:
        return sum(self.parts)

    def s_at(self, t: float) -> float:
        ds, _v = advance(self.v, self.a, self.vmax, t - self.t0)
        return min(self.s0 + ds, self.path.length)

    def speed_at(self, t: float) -> float:
        return advance(self.v, self.a, self.vmax, t - self.t0)[1]

    def xy_at(self, t: float) -> tuple[float, float]:
        return self.path.xy(self.s_at(t))

    def parts_xy_at(self, t: float) -> list[tuple[float, float]]:
        """Front, articulation(s) and aft points, following the path (for drawing a two-part tram)."""
        s = self.s_at(t)
        pts = [self.path.xy(s)]
        for p in self.parts:
            s -= p
            pts.append(self.path.xy(max(s, 0.0)))
        return pts


@dataclass(frozen=True, slots=True)
class AreaModel:
    t0: float
    area: int
    x: float
    y: float
    vx: float
    vy: float
    etype: int

    kind = KIND_AREA

    def xy_at(self, t: float) -> tuple[float, float]:
        dt = max(t - self.t0, 0.0)
        return self.x + self.vx * dt, self.y + self.vy * dt


@dataclass(frozen=True, slots=True)
class WorldModel:
    t0: float
    x: float
    y: float
    vx: float
    vy: float
    ax: float
    ay: float
    etype: int

    kind = KIND_WORLD

    def xy_at(self, t: float) -> tuple[float, float]:
        dt = max(t - self.t0, 0.0)
        h = 0.5 * dt * dt
        return self.x + self.vx * dt + self.ax * h, self.y + self.vy * dt + self.ay * h


Model = NetworkModel | AreaModel | WorldModel
