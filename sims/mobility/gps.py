"""GPS fixes: the truth plus Gaussian noise, the way a phone or vehicle locator reports it.

One function for one fix and for a whole track, so that a live mover and a benchmark's sampled truth get
noise of the same law (and a seed gives the same draws either way: one fix is a track of one point).
"""

from __future__ import annotations

import math

import numpy as np

#: horizontal RMS error (m) of the simulated receivers: a phone in a city street
GPS_SIGMA = 5.0


def gps(xy: np.ndarray, rng: np.random.Generator, sigma: float = GPS_SIGMA) -> np.ndarray:
    """Noisy fixes of `xy` (shape (2,) or (n, 2)): independent Gaussian errors per axis of sigma/sqrt(2),
    i.e. horizontal RMS `sigma`."""
    return xy + rng.normal(0.0, sigma / math.sqrt(2.0), size=xy.shape)
