"""GPS fixes: the truth plus Gaussian noise, the way a phone or vehicle locator reports it.

Two ways to draw the noise, of the same law (independent Gaussian errors per axis of sigma/sqrt(2), i.e.
horizontal RMS sigma):

- `gps(xy, rng)`: from the caller's generator, one fix or a whole track (a seed gives the same draws either
  way: one fix is a track of one point); the benchmarks' sampled truth uses it;
- `entity_gps(xy, seed, ids, times)`: counter-based, a pure function of (seed, entity id, the fix's time), so an
  entity's noise does not depend on which process takes its fixes or on which other entities are taken with
  it. The simulation's honest clients use it, so that a run split over N workers gives the fixes, messages and
  report of the run in one process (docs/simulation.md, "Workers"). Why a hash and not a generator per entity
  (`SeedSequence` / `Philox` keyed by id): one generator object per entity costs a few microseconds to make and
  a call per fix, and a restarted entity (a worker died) would begin its stream again; the hash is a few numpy
  operations over the whole tick's fixes and needs no state at all.
"""

from __future__ import annotations

import math

import numpy as np

#: horizontal RMS error (m) of the simulated receivers: a phone in a city street
GPS_SIGMA = 5.0

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # splitmix64's increment
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_U64 = (1 << 64) - 1
#: the largest |fix time| (s) whose milliseconds are whole doubles and fit the int64 key: beyond it times would
#: no longer count fixes (the cast overflows: every such time gave one and the same noise)
MAX_FIX_TIME = float(1 << 53) / 1000.0


def gps(xy: np.ndarray, rng: np.random.Generator, sigma: float = GPS_SIGMA) -> np.ndarray:
    """Noisy fixes of `xy` (shape (2,) or (n, 2)): independent Gaussian errors per axis of sigma/sqrt(2),
    i.e. horizontal RMS `sigma`."""
    return xy + rng.normal(0.0, sigma / math.sqrt(2.0), size=xy.shape)


def _mix(z: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser over uint64 arrays (wrapping arithmetic): every input bit reaches every output bit."""
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


def _uniform(h: np.ndarray) -> np.ndarray:
    """The top 53 bits of uint64 hashes as doubles in (0, 1]: never 0, so a log of 0 is never taken (k + 0.5
    rounds to even above 2**52, so the top hash gives exactly 1.0: a radius of 0, harmless)."""
    return ((h >> np.uint64(11)).astype(np.float64) + 0.5) * (1.0 / (1 << 53))


def entity_noise(seed: int, ids: np.ndarray, times: np.ndarray, sigma: float = GPS_SIGMA) -> np.ndarray:
    """Gaussian (n, 2) errors, per axis sigma/sqrt(2), each a function of (seed, entity id, fix time) only: the
    time in milliseconds counts the fixes (an entity takes at most one per tick). Box-Muller over two hashed
    uniforms per fix."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if ids.shape != t.shape:
        raise ValueError(f"one time per entity: {ids.shape[0]} ids, {t.shape[0]} times")
    if not np.isfinite(t).all():
        raise ValueError("a fix time must be finite")
    if len(t) and np.abs(t).max() >= MAX_FIX_TIME:
        raise ValueError(f"a fix time must be within +-{MAX_FIX_TIME:.4g} s (whole milliseconds), "
                         f"got {np.abs(t).max():.4g}")
    ms = np.rint(t * 1000.0).astype(np.int64)
    with np.errstate(over="ignore"):
        base = _mix(np.full(ids.shape, seed & _U64, dtype=np.uint64) + _GOLDEN)
        key = _mix(base + ids.view(np.uint64) * _GOLDEN)
        key = _mix(key ^ (ms.view(np.uint64) * _M1))
        u1 = _uniform(_mix(key + _GOLDEN))
        u2 = _uniform(_mix(key + _GOLDEN + _GOLDEN))
    r = np.sqrt(-2.0 * np.log(u1)) * (sigma / math.sqrt(2.0))
    angle = 2.0 * math.pi * u2
    return np.stack([r * np.cos(angle), r * np.sin(angle)], axis=1)


def entity_gps(xy: np.ndarray, seed: int, ids: np.ndarray, times: np.ndarray,
               sigma: float = GPS_SIGMA) -> np.ndarray:
    """Noisy fixes of `xy` (n, 2) for entities `ids` at `times`: the truth plus `entity_noise`."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return xy + entity_noise(seed, ids, times, sigma)
