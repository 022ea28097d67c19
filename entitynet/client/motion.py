"""Dead-reckoning models: what a player publishes and every receiver extrapolates, with the same code.

- `NetworkModel`: path-constrained; the front at path coordinate s0 at time t0 moves with speed v >= 0 and
  acceleration a (stopping at zero speed, capped at vmax) along an explicit list of directed edges (the
  a-priori route, or the junction rule of `NetView.next_edge`, resolved by the player and published). It
  clamps at the end of its path.
- `AreaModel`: 2D constant velocity inside an area node (pedestrians on squares, cars on parking lots).
- `WorldModel`: the DIS baselines in the world frame: FPW (first order: position + velocity), FVW (second
  order: + acceleration), and the zero-order hold used by periodic updates (velocity 0).

All models answer `xy_at(t)`; `t < t0` answers the state at t0 (receivers never extrapolate backwards), and
`t > t0 + HORIZON` the state at t0 + HORIZON, standing; no model moves faster than its entity type's
`max_speed` (entitynet/client/limits.py: a guess carried across a fix gap stays a bounded guess).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from entitynet.client.frozen import maker
from entitynet.client.kinematics import A_EPS, INF, advance, brake_plan, time_to_travel
from entitynet.client.limits import HORIZON, capped_velocity, horizon_dt, max_speed, world_state
from entitynet.client.path import Path

KIND_NETWORK, KIND_AREA, KIND_WORLD = 1, 2, 3


@dataclass(frozen=True, slots=True)
class NetworkModel:
    """Path-constrained dead reckoning: receivers extrapolate along the published edges with the same
    code the player uses to decide when it has drifted too far."""
    t0: float
    path: Path
    s0: float
    v: float
    a: float
    vmax: float
    etype: int
    parts: tuple[float, ...]  # body part lengths from the front (two entries for a two-part tram)
    stop_s: float = INF  # a planned halt (a transit stop on the route) at this path coordinate, or inf
    brake: float = 1.0  # deceleration used to halt there (m/s^2)
    plan: tuple[float, float, float, float] = (INF, 0.0, 0.0, 0.0)  # derived: t_b, s_b, v_b, b_eff

    kind = KIND_NETWORK

    def __post_init__(self) -> None:
        if math.isfinite(self.stop_s):
            tb, b = brake_plan(self.v, self.a, self.vmax, self.stop_s - self.s0, self.brake)
            if math.isfinite(tb):
                ds, vb = advance(self.v, self.a, self.vmax, tb)
                object.__setattr__(self, "plan", (tb, self.s0 + ds, vb, b))

    @property
    def length(self) -> float:
        """Body length from the parts, for the occupation of the body behind the front."""
        return sum(self.parts)

    def _state(self, dt: float) -> tuple[float, float]:
        if dt > HORIZON:  # past the horizon the model stands where it got to
            return self._state(HORIZON)[0], 0.0
        tb, sb, vb, b = self.plan
        if dt <= tb:
            ds, v = advance(self.v, self.a, self.vmax, dt)
            return self.s0 + ds, v
        if not math.isfinite(b):
            return sb, 0.0
        ds, v = advance(vb, -b, vb, dt - tb)
        return min(sb + ds, self.stop_s), v

    def s_at(self, t: float) -> float:
        """Path coordinate of the front at t, clamped to the end of the path (the model never leaves it)."""
        return min(self._state(t - self.t0)[0], self.path.length)

    def speed_at(self, t: float) -> float:
        """Extrapolated speed at t (zero past the horizon, where the model stands)."""
        return self._state(t - self.t0)[1]

    def time_to(self, d: float) -> float:
        """Seconds after t0 until the front has advanced `d` metres (math.inf if never): the inverse of
        s_at, used for validity periods so that they match the extrapolation exactly (never past HORIZON)."""
        tb, sb, _vb, _b = self.plan
        if not math.isfinite(tb) or self.s0 + d <= sb:
            t = time_to_travel(d, self.v, self.a, self.vmax)
        else:
            t = self._brake_time(d)
        return t if t <= HORIZON else INF

    def _brake_time(self, d: float) -> float:
        tb, sb, vb, b = self.plan
        if not math.isfinite(b):
            return INF
        return tb + time_to_travel(self.s0 + d - sb, vb, -b, vb)

    def xy_at(self, t: float) -> tuple[float, float]:
        """Where receivers draw the front at t: `s_at` mapped onto the path's geometry."""
        return self.path.xy(self.s_at(t))

    def xy_speed_at(self, t: float) -> tuple[float, float, float]:
        """(x, y, speed) at t in one evaluation (the player's per-fix check; `_state` written out)."""
        dt = t - self.t0
        beyond = dt > HORIZON
        if beyond:
            dt = HORIZON
        tb, sb, vb, b = self.plan
        if dt <= tb:
            v, a = self.v, self.a
            if dt > 0.0 and -A_EPS < a < A_EPS:  # `advance` at constant speed (its `_a(a)` is 0)
                s = self.s0 + v * dt
            else:
                ds, v = advance(v, a, self.vmax, dt)
                s = self.s0 + ds
        elif not math.isfinite(b):
            s, v = sb, 0.0
        else:
            ds, v = advance(vb, -b, vb, dt - tb)
            s = min(sb + ds, self.stop_s)
        path = self.path
        length = path.cum[-1]
        x, y = path.xy(length if length < s else s)  # min(s, length)
        return x, y, 0.0 if beyond else v

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
    """Constant velocity inside an area node (a square, a parking lot), where there are no edges to
    follow; the speed is capped by the type's `max_speed`."""
    t0: float
    area: int
    x: float
    y: float
    vx: float
    vy: float
    etype: int

    kind = KIND_AREA

    def xy_at(self, t: float) -> tuple[float, float]:
        """Position at t, the velocity capped and the time clamped to [t0, t0 + HORIZON]."""
        dt = horizon_dt(t - self.t0)
        vx, vy = capped_velocity(self.vx, self.vy, max_speed(self.etype))
        return self.x + vx * dt, self.y + vy * dt

    def xy_speed_at(self, t: float) -> tuple[float, float, float]:
        """(x, y, speed) at t, the shape every model answers for the player's per-fix drift check."""
        x, y = self.xy_at(t)
        if t - self.t0 > HORIZON:
            return x, y, 0.0
        return x, y, min(math.hypot(self.vx, self.vy), max_speed(self.etype))


@dataclass(frozen=True, slots=True)
class WorldModel:
    """The DIS world-frame baselines (FPW, FVW, periodic) the network model is benchmarked against,
    under the same speed cap and horizon."""
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
        """Position at t under constant acceleration, with the speed cap applied only where it binds."""
        dt = horizon_dt(t - self.t0)
        vx, vy, ax, ay = self.vx, self.vy, self.ax, self.ay
        cap2 = max_speed(self.etype) ** 2
        wx, wy = vx + ax * dt, vy + ay * dt
        # the speed along a constant acceleration is convex in time: under the cap at both ends, under it
        # throughout (the usual case, computed as without a cap)
        if vx * vx + vy * vy <= cap2 and wx * wx + wy * wy <= cap2:
            h = 0.5 * dt * dt
            return self.x + vx * dt + ax * h, self.y + vy * dt + ay * h
        dx, dy, _, _ = world_state(vx, vy, ax, ay, math.sqrt(cap2), dt)
        return self.x + dx, self.y + dy

    def xy_speed_at(self, t: float) -> tuple[float, float, float]:
        """(x, y, speed) at t, the shape every model answers for the player's per-fix drift check."""
        x, y = self.xy_at(t)
        if t - self.t0 > HORIZON:
            return x, y, 0.0
        dt = max(t - self.t0, 0.0)
        _, _, wx, wy = world_state(self.vx, self.vy, self.ax, self.ay, max_speed(self.etype), dt)
        return x, y, math.hypot(wx, wy)


Model = NetworkModel | AreaModel | WorldModel

_make_network_model = maker(NetworkModel)
_NO_PLAN = NetworkModel.__dataclass_fields__["plan"].default


def network_model(t0: float, path: Path, s0: float, v: float, a: float, vmax: float, etype: int,
                  parts: tuple[float, ...], stop_s: float = INF, brake: float = 1.0) -> NetworkModel:
    """`NetworkModel(...)` through the fast constructor, its braking plan computed as `__post_init__` does
    (the publish path builds one per update; equality is a test)."""
    plan = _NO_PLAN
    if math.isfinite(stop_s):
        tb, b = brake_plan(v, a, vmax, stop_s - s0, brake)
        if math.isfinite(tb):
            ds, vb = advance(v, a, vmax, tb)
            plan = (tb, s0 + ds, vb, b)
    return _make_network_model(t0, path, s0, v, a, vmax, etype, parts, stop_s, brake, plan)
