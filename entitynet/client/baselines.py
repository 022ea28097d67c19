"""Models in the plane: the world-frame baselines (FPW, FVW, periodic) and the network model's area part.

The baselines are what the reference compares network dead reckoning with: first-order (FPW: position and
velocity) and second-order (FVW: and acceleration) extrapolation in the world frame, and a position every
`period` seconds. They keep their own plane filter (`WorldFilter`), fed every fix, with or without a
topology; inside an area the network model publishes an `AreaModel` from the tracker's plane filter.
"""

from __future__ import annotations

import math

from entitynet.client.entities import EntityType
from entitynet.client.filters import Kinematic1D
from entitynet.client.modes import ModelKind
from entitynet.client.motion import AreaModel, Model, WorldModel


class WorldFilter:
    """The baselines' state: one kinematic filter per axis (second order for FVW, with the type's jerk noise;
    first order otherwise), fused with a Doppler velocity when the fix has one."""

    def __init__(self, kind: ModelKind, etype: EntityType) -> None:
        self.accel = kind == ModelKind.FVW
        self.q = etype.jerk_q if self.accel else 1.0
        self.kx: Kinematic1D | None = None
        self.ky: Kinematic1D | None = None

    def update(self, x: float, y: float, t: float, r: float, vel: tuple[float, float, float] | None) -> None:
        """One fix (r: its variance) and its velocity (vx, vy, variance per axis) if reported."""
        if self.kx is None:
            self.kx = Kinematic1D(x, t, r, q=self.q, accel=self.accel)
            self.ky = Kinematic1D(y, t, r, q=self.q, accel=self.accel)
        else:
            self.kx.update(x, t, r)
            self.ky.update(y, t, r)
        if vel is not None:
            self.kx.update_speed(vel[0], vel[2])
            self.ky.update_speed(vel[1], vel[2])

    def forget(self) -> None:
        """A lost entity: its next fix starts the filter afresh."""
        self.kx = self.ky = None


def plane_model(kind: ModelKind, etype: EntityType, t: float, kx: Kinematic1D, ky: Kinematic1D, area: int | None,
                ghost: Model | None, from_ghost: bool, stop_at: float | None = None) -> Model:
    """The model to publish at `t` from the plane filter (kx, ky): an `AreaModel` when the network model is
    inside `area`, else a world-frame one. `from_ghost`: continue the published model (no fix to go on);
    `stop_at`: and stand where it was at that time (a fix gap)."""
    code = etype.code
    if stop_at is not None and from_ghost and isinstance(ghost, (AreaModel, WorldModel)):
        x, y = ghost.xy_at(stop_at)
        if isinstance(ghost, AreaModel):
            return AreaModel(t, ghost.area, x, y, 0.0, 0.0, code)
        return WorldModel(t, x, y, 0.0, 0.0, 0.0, 0.0, code)
    if area is not None:
        vx, vy = kx.v, ky.v
        if math.hypot(vx, vy) < etype.v_stop:
            vx = vy = 0.0
        return AreaModel(t, area, kx.s, ky.s, vx, vy, code)
    if from_ghost and isinstance(ghost, WorldModel):
        x, y = ghost.xy_at(t)
        dt = max(t - ghost.t0, 0.0)
        return WorldModel(t, x, y, ghost.vx + ghost.ax * dt, ghost.vy + ghost.ay * dt, ghost.ax, ghost.ay, code)
    if kind == ModelKind.PERIODIC:
        return WorldModel(t, kx.s, ky.s, 0.0, 0.0, 0.0, 0.0, code)
    vx, vy = kx.v, ky.v
    ax, ay = (kx.a, ky.a) if kind == ModelKind.FVW else (0.0, 0.0)
    if math.hypot(vx, vy) < etype.v_stop:
        vx = vy = ax = ay = 0.0
    return WorldModel(t, kx.s, ky.s, vx, vy, ax, ay, code)
