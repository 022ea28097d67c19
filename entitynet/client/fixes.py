"""A fix's input checks: what the client core refuses before any state changes (bad input loses nothing).

NaN or infinite values, a time not after the previous fix, a bad accuracy, or a Doppler speed without its
heading are refused with `FixRejected`, so that a caller can drop that fix and go on with the next.
"""

from __future__ import annotations

import math


class FixRejected(ValueError):
    """A fix that cannot be used: NaN/inf, time not after the previous fix, or a bad accuracy."""


def check_fix(x: float, y: float, t: float, acc: float, last_t: float | None) -> None:
    """Raise `FixRejected` unless the fix is finite, its accuracy positive and its time after `last_t`."""
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(t)):
        raise FixRejected(f"fix with non-finite value ({x!r}, {y!r}, t={t!r})")
    if not (math.isfinite(acc) and acc > 0.0):
        raise FixRejected(f"fix accuracy must be finite and positive, got {acc!r}")
    if last_t is not None and not t > last_t:
        raise FixRejected(f"fix time {t!r} is not after the previous fix at {last_t!r}")


def velocity(speed: float | None, heading: float | None,
              speed_accuracy: float) -> tuple[float, float, float] | None:
    """(vx, vy, variance per axis) of a reported Doppler velocity, or None when there is none."""
    if speed is None:
        return None
    if heading is None and speed == 0.0:
        heading = 0.0  # receivers give no course when standing still; none is needed
    if heading is None:
        raise FixRejected("a fix's speed needs its heading (degrees clockwise from north)")
    if not (math.isfinite(speed) and speed >= 0.0 and math.isfinite(heading)):
        raise FixRejected(f"fix speed must be finite and >= 0 and heading finite, got {speed!r}, {heading!r}")
    if not (math.isfinite(speed_accuracy) and speed_accuracy > 0.0):
        raise FixRejected(f"speed accuracy must be finite and positive, got {speed_accuracy!r}")
    h = math.radians(heading)
    return speed * math.sin(h), speed * math.cos(h), speed_accuracy * speed_accuracy
