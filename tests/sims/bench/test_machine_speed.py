"""The machine's speed beside a benchmark's CPU figures (sims.bench.machine_speed) and `bench e2e`'s reading of
its server CPU at the sitting's median speed."""

from __future__ import annotations

import math

import pytest

from sims.bench.e2e_bench import AT_MEDIAN_SPEED, read_at_median_speed, summarise
from sims.bench.machine_speed import at_median_speed, work_ms


def test_the_fixed_work_is_timed_in_cpu_ms_and_scales_with_its_size():
    small, large = work_ms(lookups=20_000, repeats=3), work_ms(lookups=200_000, repeats=3)
    assert 0.0 < small < large and math.isfinite(large)
    assert large > 3 * small  # ten times the work: not a constant (a timer that reads nothing)


@pytest.mark.parametrize(("value", "run_ms", "ref_ms", "want"), [
    (0.3, 60.0, 50.0, 0.25), (0.3, 50.0, 50.0, 0.3), (0.2, 40.0, 50.0, 0.25), (0.0, 60.0, 50.0, 0.0),
    (None, 60.0, 50.0, None), (0.3, None, 50.0, None), (0.3, 0.0, 50.0, None), (0.3, 60.0, None, None),
])
def test_a_figure_at_the_median_speed_scales_by_the_work_times(value, run_ms, ref_ms, want):
    got = at_median_speed(value, run_ms, ref_ms)
    assert got == pytest.approx(want) if want is not None else got is None


def _run(cpu: float, work: float | None, **more) -> dict:
    return {"messages_per_viewer_s": 24.0, "bytes_per_viewer_s": 1674.0, "error_p95_m": 8.9,
            "server_cpu_ms_per_viewer_s": cpu, "machine_work_ms": work, **more}


def test_a_repetition_on_a_slow_machine_reads_level_at_the_median_speed_and_the_raw_spread_stays_reported():
    """The full run of 2026-12-01: a third repetition 40 % dearer for every system, the machine 40 % slower. At
    the median speed the repetitions agree; the raw figures, and the verdict on them, are kept as they were."""
    runs = {"redis-disc": [_run(0.20, 50.0), _run(0.19, 48.0), _run(0.28, 70.0)],
            "entitynet": [_run(0.18, 49.0), _run(0.17, 47.0), _run(0.25, 71.0)]}
    speed = read_at_median_speed(runs)
    assert speed["work_ms_median"] == pytest.approx(49.5)
    assert speed["work_spread"] == pytest.approx((71.0 - 49.5) / 49.5)
    s = summarise(runs)
    for name in runs:
        assert not s[name]["stable"] and s[name]["server_cpu_ms_per_viewer_s_spread"] > 0.15
        assert s[name]["stable_at_median_speed"] and s[name][f"{AT_MEDIAN_SPEED}_spread"] < 0.05
    assert s["redis-disc"]["server_cpu_ms_per_viewer_s_runs"] == [0.20, 0.19, 0.28]
    assert s["redis-disc"][AT_MEDIAN_SPEED] == pytest.approx(0.20 * 49.5 / 50.0)


def test_a_run_without_a_speed_reading_has_no_figure_at_the_median_speed_and_others_still_count():
    runs = {"mqtt-disc": [_run(1.0, None), _run(1.0, 50.0), _run(1.1, 52.0)]}
    read_at_median_speed(runs)
    assert runs["mqtt-disc"][0][AT_MEDIAN_SPEED] is None
    assert summarise(runs)["mqtt-disc"][f"{AT_MEDIAN_SPEED}_runs"] == pytest.approx([1.0 * 51 / 50, 1.1 * 51 / 52])


def test_no_speed_reading_at_all_is_none_not_a_division_by_zero():
    runs = {"entitynet": [_run(0.2, None)]}
    assert read_at_median_speed(runs) == {"work_ms_median": None, "work_ms_runs": [], "work_spread": None}
    assert summarise(runs)["entitynet"][AT_MEDIAN_SPEED] is None
