"""Delay lines: exact delayed ZOH segments, runtime delay change, history retention."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.interfaces import to_ns
from tank_control.core.plants.delay_line import DelayLine, HermiteDelayLine


def _signal(t: float) -> float:
    """The test input: 0 before 1 s, 2 on [1, 2.5), -1 on [2.5, 4), 5 after."""
    if t < 1.0:
        return 0.0
    if t < 2.5:
        return 2.0
    if t < 4.0:
        return -1.0
    return 5.0


def _pushed_line(max_delay: float, ts: float, t_end: float) -> DelayLine:
    line = DelayLine(max_delay, initial=0.0)
    for k in range(int(round(t_end / ts))):
        line.push(to_ns(k * ts), _signal(k * ts))
    return line


def test_segments_reproduce_a_delay_that_is_not_a_multiple_of_the_sample_time():
    ts, delay = 0.5, 1.3
    line = _pushed_line(10.0, ts, 8.0)
    for k in range(12):
        t0 = k * ts
        pieces = line.segments(to_ns(t0), ts, delay)
        assert sum(d for d, _ in pieces) == pytest.approx(ts, abs=1e-15)
        # Each piece has the value of the delayed signal at its midpoint.
        start = t0
        for duration, value in pieces:
            assert duration > 0
            assert value == _signal(start + duration / 2 - delay)
            start += duration
    # A switch at 1.0 s appears at 2.3 s: inside the sample [2.0, 2.5).
    assert line.segments(to_ns(2.0), ts, delay) == [
        pytest.approx((0.3, 0.0)), pytest.approx((0.2, 2.0))]


def test_zero_delay_returns_the_held_input():
    line = _pushed_line(5.0, 0.5, 6.0)
    assert line.segments(to_ns(1.0), 0.5, 0.0) == [(0.5, 2.0)]


def test_delay_change_replays_the_stored_history():
    ts = 0.25
    line = _pushed_line(20.0, ts, 10.0 + ts)
    # At t = 10 s a delay of 9 s reads the signal of [1, 1.25) again.
    assert line.segments(to_ns(10.0), ts, 9.0) == [(ts, 2.0)]
    assert line.segments(to_ns(10.0), ts, 7.5) == [(ts, -1.0)]  # reads [2.5, 2.75)
    line = _pushed_line(20.0, ts, 24.0 + ts)
    for delay in (0.0, 3.7, 7.4, 9.9, 20.0):
        for duration, value in line.segments(to_ns(24.0), 0.1, delay):
            assert value == _signal(24.0 + 0.05 - delay)


def test_history_is_kept_for_max_delay_and_no_longer():
    line = DelayLine(max_delay=5.0, initial=0.0)
    for k in range(2000):          # the input changes every sample: worst case
        line.push(to_ns(k * 0.01), float(k))
    assert len(line) <= 5.0 / 0.01 + 2 + 64      # pruned in batches of 64
    # The oldest readable instant still has the right value.
    (duration, value), = line.segments(to_ns(19.99), 0.01, 5.0)
    assert value == float(1499)
    with pytest.raises(ValueError, match='delay'):
        line.segments(to_ns(19.99), 0.01, 5.5)
    with pytest.raises(ValueError, match='older than max_delay'):
        line.segments(to_ns(10.0), 0.01, 5.0)


def test_unchanged_values_are_not_stored():
    line = DelayLine(max_delay=100.0, initial=1.0)
    for k in range(100):
        line.push(to_ns(k), 1.0 if k < 50 else 3.0)
    assert len(line) == 1


def test_times_must_not_go_back():
    line = DelayLine(max_delay=1.0)
    line.push(to_ns(2.0), 1.0)
    with pytest.raises(ValueError, match='t_ns'):
        line.push(to_ns(1.0), 2.0)


def test_hermite_line_is_exact_on_the_grid_and_for_cubics():
    def f(t):
        return 1.0 + 0.5 * t - 0.2 * t ** 2 + 0.03 * t ** 3

    def df(t):
        return 0.5 - 0.4 * t + 0.09 * t ** 2

    line = HermiteDelayLine(max_delay=10.0, initial=f(0.0))
    grid = np.cumsum([0.3, 0.1, 0.45, 0.2, 0.7, 0.25])
    previous = 0.0
    for t in grid:
        line.append(t, f(t), df(previous), df(t))
        previous = t
    now = grid[-1]
    for t in np.linspace(0.0, now, 37):
        assert line.delayed(now, now - t) == pytest.approx(f(t), abs=1e-13)
    assert line.value_at(-1.0) == f(0.0)          # pre-filled history


def test_hermite_line_keeps_kinks():
    # A ramp that stops: slope 1 on [0, 1], 0 on [1, 2]; exact with one-sided slopes.
    line = HermiteDelayLine(max_delay=5.0, initial=0.0)
    line.append(1.0, 1.0, 1.0, 1.0)
    line.append(2.0, 1.0, 0.0, 0.0)
    assert line.value_at(0.5) == pytest.approx(0.5, abs=1e-15)
    assert line.value_at(1.5) == pytest.approx(1.0, abs=1e-15)
    assert math.isclose(line.delayed(2.0, 1.75), 0.25)
