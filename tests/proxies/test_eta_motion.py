"""ETA-driven motion: monotone, never standing between stops, on time with exact ETAs, sane with minute ETAs and
late answers, carrying on through an outage."""

from __future__ import annotations

import random

import numpy as np
import pytest

from proxies.eta_motion import EtaMotion, Limits

STOPS = [0.0, 400.0, 800.0, 1200.0, 1600.0]
SCHED = [(0.0, 0.0), (90.0, 110.0), (200.0, 220.0), (310.0, 330.0), (420.0, 420.0)]


def _motion(g: float = 60.0) -> EtaMotion:
    return EtaMotion(STOPS, SCHED, Limits(vmax=14.0, accel=1.0, brake=1.0), granularity=g)


def _run(m: EtaMotion, truth_arr: list[float], dwell: float, g: float, poll: float, latency: float,
         t_end: float, rng: random.Random):
    """Feed minute-rounded ETAs of a vehicle arriving at truth_arr[k], every `poll` s, `latency` s late."""
    out = []
    t = 0.0
    next_poll = 0.0
    while t <= t_end:
        if t >= next_poll:
            next_poll += poll
            seen = t - latency
            passed = [k for k in range(len(STOPS)) if truth_arr[k] + dwell < seen]
            nxt = max(passed) + 1 if passed else 0
            if nxt < len(STOPS):
                etas = {k: (round(truth_arr[k] / g) * g if g else truth_arr[k]) for k in range(nxt, len(STOPS))}
                m.observe(t, etas, at_stop=nxt if truth_arr[nxt] <= seen else None)
        s, v = m.advance(t)
        out.append((t, s, v, m.standing))
        t += 0.5
    return out


@pytest.mark.parametrize("g, poll, latency", [(1.0, 20.0, 0.0), (60.0, 20.0, 5.0), (60.0, 60.0, 8.0)])
def test_monotone_and_never_standing_between_stops(g, poll, latency):
    rng = random.Random(1)
    truth = [0.0, 95.0, 210.0, 330.0, 445.0]
    trace = _run(_motion(g), truth, 15.0, g, poll, latency, 520.0, rng)
    s = np.array([p[1] for p in trace])
    assert np.all(np.diff(s) >= -1e-9), "moved backwards"
    for _t, si, v, _standing in trace:
        if v == 0.0 and si > 0.0:
            assert min(abs(si - x) for x in STOPS) < 1e-6, f"stood at {si} between stops"
    assert s[-1] == pytest.approx(STOPS[-1])  # reached the end


def test_exact_etas_arrive_on_time():
    truth = [0.0, 95.0, 210.0, 330.0, 445.0]
    trace = _run(_motion(0.0), truth, 15.0, 0.0, 5.0, 0.0, 500.0, random.Random(0))
    for k in (1, 2, 3):
        t_arr = next(t for t, s, _v, _st in trace if s >= STOPS[k] - 1e-6)
        assert abs(t_arr - truth[k]) <= 3.0, (k, t_arr, truth[k])


def test_reported_past_a_stop_it_goes_through_without_stopping():
    m = _motion(60.0)
    m.observe(0.0, {1: 300.0, 2: 400.0})  # a slow ETA: it dawdles
    m.advance(30.0)
    s_before = m.s
    m.observe(30.0, {3: 120.0})  # the tracker has it past stops 1 and 2 already
    speeds = []
    for t in np.arange(30.5, 120.0, 0.5):
        s, v = m.advance(t)
        speeds.append((s, v))
        if s >= STOPS[3] - 1e-6:
            break
    assert s_before < STOPS[1]
    assert all(v > 0.0 for s, v in speeds if s < STOPS[3] - 1e-6)  # no halt at stops 1 and 2
    assert speeds[-1][0] >= STOPS[2]


def test_an_outage_keeps_it_moving_on_the_last_etas_then_the_schedule():
    m = _motion(60.0)
    m.observe(0.0, {1: 90.0, 2: 210.0}, aimed={1: 90.0, 2: 200.0})  # 10 s late at stop 2
    for t in np.arange(0.5, 600.0, 0.5):
        m.advance(t)
    assert m.s == pytest.approx(STOPS[-1])  # went all the way, past the ETAs it had, on the schedule


def test_bad_routes_are_refused():
    with pytest.raises(ValueError):
        EtaMotion([0.0, 10.0, 5.0], [(0, 0)] * 3, Limits(10.0))
    with pytest.raises(ValueError):
        EtaMotion([], [], Limits(10.0))


def test_stops_served_counts_the_stops_it_stood_at_not_those_it_passed():
    m = _motion(0.0)
    m.observe(0.0, {1: 95.0, 2: 210.0, 3: 330.0, 4: 445.0})
    for t in np.arange(0.5, 250.0, 0.5):
        m.advance(t)
    assert m.stops_served == 2  # stood at stops 1 and 2 (stop 0, where it started, is not an arrival)
    m.observe(250.0, {4: 330.0})  # the tracker has it past stop 3: it goes through
    for t in np.arange(250.5, 600.0, 0.5):
        m.advance(t)
    assert m.finished and m.stops_served == 3  # and the last stop
