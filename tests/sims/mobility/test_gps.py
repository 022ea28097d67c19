"""Per-entity GPS noise (`entity_gps`): a function of (seed, entity id, fix time) only, of the documented law."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sims.mobility.gps import entity_gps, entity_noise


def test_an_entity_gets_the_same_noise_whatever_else_is_drawn_with_it():
    ids = np.arange(1, 101)
    times = np.full(100, 28800.5)
    whole = entity_noise(7, ids, times)
    parts = np.concatenate([entity_noise(7, ids[k::3], times[k::3]) for k in range(3)])
    order = np.concatenate([ids[k::3] for k in range(3)])
    assert np.array_equal(parts[np.argsort(order)], whole)  # split as workers split by id: the same numbers
    assert np.array_equal(entity_noise(7, ids[::-1], times), whole[::-1])


def test_seed_id_and_time_each_change_the_noise():
    one = entity_noise(7, [5], [10.0])
    assert not np.array_equal(one, entity_noise(8, [5], [10.0]))
    assert not np.array_equal(one, entity_noise(7, [6], [10.0]))
    assert not np.array_equal(one, entity_noise(7, [5], [10.5]))
    assert np.array_equal(one, entity_noise(7, [5], [10.0]))
    assert np.isfinite(entity_noise(-3, [0], [-1.0])).all()  # negative seeds and times are keys like any other


def test_the_noise_has_the_law_of_gps():
    """Independent Gaussian errors per axis of sigma/sqrt(2): horizontal RMS sigma, no correlation."""
    n = 100_000
    noise = entity_noise(1, np.arange(n) % 97, np.arange(n) * 0.5, sigma=5.0)
    assert noise.mean(axis=0) == pytest.approx([0.0, 0.0], abs=0.05)
    assert noise.std(axis=0) == pytest.approx([5.0 / math.sqrt(2.0)] * 2, rel=0.02)
    assert math.sqrt((noise**2).sum(axis=1).mean()) == pytest.approx(5.0, rel=0.02)
    assert abs(np.corrcoef(noise[:, 0], noise[:, 1])[0, 1]) < 0.02
    assert abs(np.corrcoef(noise[:-1, 0], noise[1:, 0])[0, 1]) < 0.02  # successive fixes independent
    inside_1_sigma = np.mean(np.abs(noise[:, 0]) < 5.0 / math.sqrt(2.0))
    assert inside_1_sigma == pytest.approx(0.6827, abs=0.01)  # Gaussian, not uniform or clipped


def test_fixes_are_the_truth_plus_the_noise_and_bad_input_is_refused():
    xy = np.array([[10.0, 20.0], [30.0, 40.0]])
    fixes = entity_gps(xy, 3, [1, 2], [5.0, 5.0], sigma=2.0)
    assert np.allclose(fixes - xy, entity_noise(3, [1, 2], [5.0, 5.0], sigma=2.0), rtol=0.0, atol=1e-12)
    assert not np.allclose(fixes, xy, atol=1e-3)
    with pytest.raises(ValueError, match="one time per entity"):
        entity_noise(3, [1, 2], [5.0])
    with pytest.raises(ValueError, match="finite"):
        entity_noise(3, [1], [math.nan])
    assert entity_noise(3, [], []).shape == (0, 2)


@pytest.mark.parametrize("t", [1e16, -1e16, 2e16, 9.1e12])
def test_a_fix_time_beyond_exact_milliseconds_is_refused(t):
    """Beyond 2**53 ms the time no longer counts fixes (the int64 cast overflowed, every such time gave one
    and the same noise, with a RuntimeWarning): refused as clearly as NaN."""
    with pytest.raises(ValueError, match="fix time"):
        entity_noise(1, [1, 1], [t, t * 1.5])


def test_the_largest_exact_fix_times_still_differ():
    t = 9.0e12  # about 285,000 years of simulated time: still whole milliseconds
    a, b = entity_noise(1, [1, 1], [t, t + 0.001])
    assert np.isfinite(a).all() and not np.array_equal(a, b)


def test_the_uniforms_never_reach_zero_and_the_extremes_give_finite_noise():
    from sims.mobility.gps import _uniform

    h = np.array([0, 1, (1 << 64) - 1], dtype=np.uint64)
    u = _uniform(h)
    assert (u > 0.0).all() and (u <= 1.0).all() and np.isfinite(np.log(u)).all()
