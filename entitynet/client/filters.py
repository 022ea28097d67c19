"""Scalar Kalman filters for noisy fixes, written out by hand (pure floats: ~2 us per update).

`Kinematic1D` tracks (position, speed, acceleration) along one axis: the path coordinate for network dead
reckoning, or x and y separately for the world-frame baselines. With `accel=False` it is the constant
velocity filter (acceleration fixed at 0). Process noise is white jerk (or white acceleration) of density q.
"""

from __future__ import annotations

import math
from struct import Struct

from entitynet.client.state import _COMPILED, F_COL, I_COL, Bound, column

_KALMAN_ROW = getattr(_COMPILED, "kalman_row", None)  # the compiled row update, where pip built it

_READ, _WRITE = Struct("=11d"), Struct("=10d")  # the row's filter fields read and written at once (C speed)
_KS, _KACC = F_COL["ks"], I_COL["kacc"]  # (ks, kv, ka, p00 .. p22, kt, kq: adjacent columns, in this order)
assert [F_COL[n] - _KS for n in ("kv", "ka", "p00", "p01", "p02", "p11", "p12", "p22", "kt", "kq")] == [*range(1, 11)]


def kalman_update(state: tuple, z: float, t: float, r: float) -> tuple[tuple, float]:
    """One measurement z (variance r) taken at t folded into `state` = (s, v, a, p00, p01, p02, p11, p12, p22,
    t0, q, accel): ((s, v, a, p00, p01, p02, p11, p12, p22, t0) after it, the innovation). A plain function
    over a tuple so that a filter with slots and one in a client-state row share the one arithmetic.

    `predict` is written out here (the same operations in the same order): this runs once per fix."""
    s, v, a, p00, p01, p02, p11, p12, p22, t0, q, accel = state
    dt = t - t0
    if dt > 0.0:
        h = 0.5 * dt * dt
        if accel:
            s += v * dt + a * h
            v += a * dt
            r00 = p00 + dt * p01 + h * p02
            r01 = p01 + dt * p11 + h * p12
            r02 = p02 + dt * p12 + h * p22
            r11 = p11 + dt * p12
            r12 = p12 + dt * p22
            dt2 = dt * dt
            dt3 = dt2 * dt
            p00 = r00 + dt * r01 + h * r02 + q * dt3 * dt2 / 20.0
            p01 = r01 + dt * r02 + q * dt2 * dt2 / 8.0
            p02 = r02 + q * dt3 / 6.0
            p11 = r11 + dt * r12 + q * dt3 / 3.0
            p12 = r12 + q * dt2 / 2.0
            p22 = p22 + q * dt
        else:
            s += v * dt
            p00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q * dt * dt * dt / 3.0
            p01 = p01 + dt * p11 + q * dt * dt / 2.0
            p11 = p11 + q * dt
        t0 = t
    y = z - s
    sden = p00 + r
    if not sden > 0.0:
        return (s, v, a, p00, p01, p02, p11, p12, p22, t0), y
    k0, k1, k2 = p00 / sden, p01 / sden, p02 / sden
    return (s + k0 * y, v + k1 * y, a + k2 * y, p00 - k0 * p00, p01 - k0 * p01, p02 - k0 * p02,
            p11 - k1 * p01, p12 - k1 * p02, p22 - k2 * p02, t0), y


class KinematicMath:
    """One-axis Kalman filter on (s, v, a) with hand-written scalar covariance terms: numpy would cost
    more per fix than the arithmetic itself. The arithmetic only: `Kinematic1D` keeps its state in slots,
    `RowKinematic` in a client-state row (the along-path filter, which the fleet core updates over arrays)."""
    __slots__ = ()
    FIELDS = ("s", "v", "a", "p00", "p01", "p02", "p11", "p12", "p22", "t", "q", "accel")

    def reset(self, s: float, t: float, r: float, *, q: float = 0.5, accel: bool = True,
              v0_var: float = 100.0, a0_var: float = 4.0) -> None:
        """Start at position s at time t (r: its variance), standing, with a wide speed (and acceleration)."""
        self.s, self.v, self.a, self.t = s, 0.0, 0.0, t
        self.p00, self.p01, self.p02 = r, 0.0, 0.0
        self.p11, self.p12 = v0_var, 0.0
        self.p22 = a0_var if accel else 0.0
        self.q, self.accel = q, accel

    def predict(self, t: float) -> None:
        """Advance the state and covariance to t (no-op if t is not later). The plain reference that the
        written-out copy inside `update` is tested against."""
        dt = t - self.t
        if dt <= 0.0:
            return
        h = 0.5 * dt * dt
        q = self.q
        p00, p01, p02, p11, p12, p22 = self.p00, self.p01, self.p02, self.p11, self.p12, self.p22
        if self.accel:
            self.s += self.v * dt + self.a * h
            self.v += self.a * dt
            r00 = p00 + dt * p01 + h * p02
            r01 = p01 + dt * p11 + h * p12
            r02 = p02 + dt * p12 + h * p22
            r11 = p11 + dt * p12
            r12 = p12 + dt * p22
            dt2 = dt * dt
            dt3 = dt2 * dt
            self.p00 = r00 + dt * r01 + h * r02 + q * dt3 * dt2 / 20.0
            self.p01 = r01 + dt * r02 + q * dt2 * dt2 / 8.0
            self.p02 = r02 + q * dt3 / 6.0
            self.p11 = r11 + dt * r12 + q * dt3 / 3.0
            self.p12 = r12 + q * dt2 / 2.0
            self.p22 = p22 + q * dt
        else:
            self.s += self.v * dt
            self.p00 = p00 + 2.0 * dt * p01 + dt * dt * p11 + q * dt * dt * dt / 3.0
            self.p01 = p01 + dt * p11 + q * dt * dt / 2.0
            self.p11 = p11 + q * dt
        self.t = t

    def update(self, z: float, t: float, r: float) -> float:
        """Fold in a measurement z (variance r) taken at t; returns the innovation (`kalman_update`)."""
        new, y = kalman_update(self._state(), z, t, r)
        self._set_state(new)
        return y

    def update_sv(self, z: float, t: float, r: float) -> tuple[float, float]:
        """`update`, returning the new (s, v) instead of the innovation (one read less on the hot path)."""
        new, _y = kalman_update(self._state(), z, t, r)
        self._set_state(new)
        return new[0], new[1]

    def update_speed(self, z: float, r: float) -> float:
        """Fold in a measured speed z (variance r) taken at the filter's time (right after `update`): a
        Doppler speed from the receiver, far less noisy than differences of positions."""
        p01, p11, p12 = self.p01, self.p11, self.p12
        y = z - self.v
        sden = p11 + r
        if not sden > 0.0:
            return y
        k0, k1, k2 = p01 / sden, p11 / sden, p12 / sden
        self.s += k0 * y
        self.v += k1 * y
        if self.accel:
            self.a += k2 * y
            self.p02 -= k0 * p12
            self.p22 -= k2 * p12
            self.p12 = p12 - k1 * p12
        self.p00 -= k0 * p01
        self.p01 = p01 - k0 * p11
        self.p11 = p11 - k1 * p11
        return y

    def flip(self, total: float) -> None:
        """Re-express the state on the reversed path (s -> total - s); the covariance is unchanged."""
        self.s, self.v, self.a = total - self.s, -self.v, -self.a

    def shift(self, ds: float) -> None:
        """Move the origin of s by ds (the path was trimmed in front): the state keeps its meaning."""
        self.s -= ds

    def speed_sigma(self) -> float:
        """Standard deviation of the speed estimate: reversing needs the speed to be negative beyond it."""
        return math.sqrt(max(self.p11, 0.0))


class Kinematic1D(KinematicMath):
    """A filter with its own state (the world-frame baselines and the area filters)."""
    __slots__ = KinematicMath.FIELDS

    def _state(self) -> tuple:
        return (self.s, self.v, self.a, self.p00, self.p01, self.p02, self.p11, self.p12, self.p22, self.t,
                self.q, self.accel)

    def _set_state(self, new: tuple) -> None:
        self.s, self.v, self.a, self.p00, self.p01, self.p02, self.p11, self.p12, self.p22, self.t = new

    def __init__(self, s: float, t: float, r: float, *, q: float = 0.5, accel: bool = True,
                 v0_var: float = 100.0, a0_var: float = 4.0) -> None:
        self.reset(s, t, r, q=q, accel=accel, v0_var=v0_var, a0_var=a0_var)


class RowKinematic(KinematicMath, Bound):
    """The along-path filter of a client-state row (entitynet/client/state.py): the same arithmetic on the
    row's ks, kv, ka, p.., kt, kq and kacc, the fields the fleet core's `kf_update` works on over arrays."""
    __slots__ = ()
    s, v, a, t, q = column("ks"), column("kv"), column("ka"), column("kt"), column("kq")
    p00, p01, p02 = column("p00"), column("p01"), column("p02")
    p11, p12, p22 = column("p11"), column("p12"), column("p22")
    accel = column("kacc", "bool")

    def _state(self) -> tuple:
        return (*_READ.unpack_from(self._st.f, 8 * (self._fb + _KS)), self._st.i[self._ib + _KACC] != 0)

    def _set_state(self, new: tuple) -> None:
        _WRITE.pack_into(self._st.f, 8 * (self._fb + _KS), *new)

    def update_sv(self, z: float, t: float, r: float) -> tuple[float, float]:
        """`KinematicMath.update_sv` (the reference) compiled where pip built `_columns.kalman_row`: the same
        operations in C on the row in place, once per usual fix."""
        if _KALMAN_ROW is None:
            return KinematicMath.update_sv(self, z, t, r)
        st = self._st
        return _KALMAN_ROW(st.f, self._fb + _KS, st.i[self._ib + _KACC], z, t, r)
