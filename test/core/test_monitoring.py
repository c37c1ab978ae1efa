"""Control performance indices (core/monitoring): each against a case whose answer is known in
closed form or computed here independently, the verdict lines, and the live LoopMonitor."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tank_control.core.monitoring import (LoopMonitor, MonitorConfig, assess, diagnostics_line,
                                          loop_monitors, verdict)
from tank_control.core.monitoring import indices as ix


def noise_loop(n: int, kp: float, a: float = 0.9, gain: float = 1.0, d: int = 3, seed: int = 0
               ) -> tuple[np.ndarray, np.ndarray]:
    """A loop whose only disturbance is white measurement noise: plant y_k = a·y_{k−1} +
    gain·(1 − a)·u_{k−1−d}, proportional controller u_k = −kp·m_k on the measurement
    m = y + noise. Returns the measured error −m and the sensitivity's impulse response.
    (Proportional: an integrating controller puts a zero of S on the unit circle, which a
    finite AR model cannot represent — docs/monitoring.md, limitations.)"""
    rng = np.random.default_rng(seed)

    def run(noise: np.ndarray) -> np.ndarray:
        y = np.zeros(noise.size)
        u = np.zeros(noise.size)
        m = np.zeros(noise.size)
        for k in range(noise.size):
            prev = y[k - 1] if k else 0.0
            ud = u[k - 1 - d] if k - 1 - d >= 0 else 0.0
            y[k] = a * prev + gain * (1 - a) * ud
            m[k] = y[k] + noise[k]
            u[k] = -kp * m[k]
        return m

    impulse = np.zeros(400)
    impulse[0] = 1.0
    return -run(rng.standard_normal(n)), run(impulse)


def test_harris_index_of_a_loop_near_minimum_variance_is_one_over_the_sensitivity_norm() -> None:
    """With white measurement noise as the only disturbance the minimum-variance controller does
    nothing (index 1); a proportional controller of low gain is near it. The error is S(q)·noise
    with S = 1 + terms delayed by the dead time (d + 1 samples with the hold), so the index is
    1/Σ s_i² exactly — computed here from the sensitivity's impulse response."""
    e, s = noise_loop(20000, kp=1.0)
    expected = 1.0 / float(np.sum(s ** 2))
    np.testing.assert_allclose(s[1:4], 0.0, atol=1e-15)     # the first b = 4 terms: 1, 0, 0, 0
    assert 0.9 < expected < 0.99                              # near minimum variance
    assert ix.harris_index(e, b=4) == pytest.approx(expected, abs=0.02)
    # a tighter controller amplifies the noise: lower index, again 1/Σ s²
    e2, s2 = noise_loop(20000, kp=3.0)
    expected2 = 1.0 / float(np.sum(s2 ** 2))
    assert expected2 < expected - 0.1
    assert ix.harris_index(e2, b=4) == pytest.approx(expected2, abs=0.03)


def test_harris_index_of_white_noise_and_of_an_ar1_with_known_answer() -> None:
    rng = np.random.default_rng(3)
    assert ix.harris_index(rng.standard_normal(5000), b=1) == pytest.approx(1.0, abs=0.01)
    # AR(1) x_k = φ x_{k−1} + ε: ψ_i = φ^i, σ²_mv(b) = σ² Σ_{i<b} φ^{2i}, σ²_x = σ²/(1 − φ²)
    phi, n = 0.8, 40000
    eps = rng.standard_normal(n)
    x = np.zeros(n)
    for k in range(1, n):
        x[k] = phi * x[k - 1] + eps[k]
    for b in (1, 3):
        expected = sum(phi ** (2 * i) for i in range(b)) * (1 - phi ** 2)
        assert ix.harris_index(x, b=b) == pytest.approx(expected, abs=0.02)
    # too few samples, a constant error: no index
    assert ix.harris_index(np.zeros(5000), b=1) is None
    assert ix.harris_index(rng.standard_normal(30), b=1) is None


def test_oscillation_period_and_amplitude_of_a_noisy_sine_and_none_in_white_noise() -> None:
    rng = np.random.default_rng(1)
    ts, period, amplitude = 0.5, 12.0, 1.5
    t = np.arange(4000) * ts
    x = amplitude * np.sin(2 * np.pi * t / period) + 0.3 * rng.standard_normal(t.size)
    osc = ix.oscillation(x, ts)
    # independent: the periodogram's peak
    spectrum = np.abs(np.fft.rfft(x - x.mean())) ** 2
    f = np.fft.rfftfreq(x.size, ts)
    assert osc['detected']
    assert osc['period'] == pytest.approx(1.0 / f[np.argmax(spectrum)], rel=0.03)
    assert osc['period'] == pytest.approx(period, rel=0.03)
    assert osc['amplitude'] == pytest.approx(math.sqrt(amplitude ** 2 + 2 * 0.3 ** 2), rel=0.05)
    detected = [ix.oscillation(np.random.default_rng(s).standard_normal(2000), ts)['detected']
                for s in range(20)]
    assert not any(detected)


def test_horch_cross_correlation_odd_is_stiction_even_is_not() -> None:
    """[Horch1999]: OP and PV 90° apart (an integrating controller around a sticky valve):
    odd cross-correlation, index near 1; in phase opposition (a loop near instability): even,
    index near 0."""
    t = np.arange(3000) * 0.1
    w = 2 * np.pi / 20.0
    u = np.sin(w * t)
    assert ix.stiction(u, -np.cos(w * t), 200) > 0.9
    assert ix.stiction(u, -np.sin(w * t), 200) < 0.1
    # square PV, triangular OP (the stick-slip shapes): odd
    y = np.sign(np.sin(w * t))
    op = np.cumsum(-y) * 0.1
    assert ix.stiction(op, y, 200) > 0.8


def test_saturation_and_setpoint_iae_counted_directly() -> None:
    u = np.array([0.0, 10.0, 10.0, -10.0, 5.0, 10.0000000001])
    assert ix.saturation_pct(u, -10.0, 10.0) == pytest.approx(100 * 4 / 6)
    assert ix.saturation_pct(u, -math.inf, math.inf) is None
    t = np.arange(10) * 0.5
    r = np.array([0, 0, 1, 1, 1, 1, 3, 3, 3, 3], dtype=float)
    y = np.array([0, 0, 0, .5, 1, 1, 1, 2, 3, 3], dtype=float)
    changes = ix.setpoint_iae(t, r, y)
    assert [(c['time'], c['from'], c['to']) for c in changes] == [(1.0, 0.0, 1.0), (3.0, 1.0, 3.0)]
    assert changes[0]['iae'] == pytest.approx(0.5 * (1 + 0.5))
    assert changes[1]['iae'] == pytest.approx(0.5 * (2 + 1))


def body(**changes):
    base = {'samples': 1000, 'harris_index': 0.8, 'manual_pct': None, 'fail_safe_pct': None,
            'saturation_pct': 0.0, 'ms': None,
            'oscillation': {'detected': False, 'period': None},
            'stiction': {'detected': False, 'index': None}}
    base.update(changes)
    return base


def test_verdict_lines() -> None:
    assert verdict(body()) == 'good'
    assert verdict(body(saturation_pct=34.2)) == 'saturated 34 % of the time'
    assert verdict(body(manual_pct=80.0, saturation_pct=90.0)) == 'in manual 80 % of the time'
    assert verdict(body(fail_safe_pct=12.0)) == 'fail-safe output 12 % of the time'
    osc = {'detected': True, 'period': 12.0}
    assert verdict(body(oscillation=osc, ms=2.94, stiction={'detected': False, 'index': 0.1})) \
        == 'retune (oscillating, period 12 s, Ms 2.9, no stiction)'
    assert verdict(body(oscillation=osc, stiction={'detected': True, 'index': 0.8})) \
        == 'valve: stiction suspected — do not retune'
    assert verdict(body(harris_index=0.2)).startswith('retune (sluggish: Harris index 0.20')


def test_assess_leaves_out_non_finite_rows_and_is_json_ready() -> None:
    rng = np.random.default_rng(0)
    n = 1000
    t = np.arange(n) * 1.0
    y = rng.standard_normal(n)
    y[10] = math.nan
    u = np.full(n, math.inf)
    u[:] = rng.standard_normal(n)
    u[20] = math.inf
    out = assess(t, y, np.zeros(n), u, 1.0, u_limits=(-10.0, 10.0))
    assert out['samples'] == n - 2
    assert out['verdict'] == 'good'
    json.dumps(out, allow_nan=False)


def test_loop_monitor_recomputes_every_period_over_its_window() -> None:
    """Live: one update per sample; a summary every monitor.period over the last
    monitor.window, equal to assess() of that window; bad samples counted, never raised."""
    ts = 0.5
    config = MonitorConfig(window=300.0, period=50.0, dead_time=2.0)
    monitor = LoopMonitor(ts, config, u_limits=(-50.0, 50.0), ms=1.7)
    assert monitor.summary()['verdict'] == 'no data' and monitor.level() == 0
    rng = np.random.default_rng(2)
    t = np.arange(2000) * ts
    y = 2.0 * np.sin(2 * np.pi * t / 30.0) + 0.1 * rng.standard_normal(t.size)
    u = -y * 3.0
    published = []
    for k in range(t.size):
        out = monitor.update(t[k], y[k], 0.0, u[k])
        if out is not None:
            published.append(out)
    assert len(published) == t.size // 100
    last = monitor.summary()
    window = slice(t.size - 600, t.size)
    offline = assess(t[window], y[window], np.zeros(600), u[window], ts, config,
                     u_limits=(-50.0, 50.0), ms=1.7)
    assert last['samples'] == 600
    assert last['verdict'] == offline['verdict'] == \
        'retune (oscillating, period 30 s, Ms 1.7, no stiction)'
    assert last['oscillation']['period'] == pytest.approx(offline['oscillation']['period'])
    assert monitor.level() == 1
    json.dumps(last, allow_nan=False)


def test_loop_monitors_of_a_controller_and_their_diagnostics_line() -> None:
    """What controller_node wires: one monitor per output paired with the input at the same
    position, the output limits per input, one /diagnostics line (WARN unless every loop is
    good or has no data yet)."""
    monitors = loop_monitors(MonitorConfig(window=100.0, period=100.0), 1.0, ['h', 'T'],
                             ['F_H', 'F_C'], {'F_H': (0.0, 10.0)})
    assert list(monitors) == ['h', 'T'] and monitors['h'][0] == 'F_H'
    assert monitors['h'][1].u_limits == (0.0, 10.0)
    assert monitors['T'][1].u_limits == (-math.inf, math.inf)
    assert loop_monitors(MonitorConfig(), 1.0, ['a', 'b'], ['u']) == {}
    assert diagnostics_line(monitors) == (0, 'loop h: no data; loop T: no data')
    rng = np.random.default_rng(0)
    for k in range(100):
        monitors['h'][1].update(k, rng.standard_normal(), 0.0, 10.0)       # at its limit
        monitors['T'][1].update(k, rng.standard_normal(), 0.0, 1.0)
    assert diagnostics_line(monitors) == (1, 'loop h: saturated 100 % of the time; loop T: good')


def test_loop_monitor_counts_fault_samples_for_the_fail_safe_time() -> None:
    """A measurement fault (non-finite or non-numeric value) is left out of the indices but its
    sample counts for the fail-safe and manual times; nothing raises."""
    monitor = LoopMonitor(1.0, MonitorConfig(window=100.0, period=100.0))
    rng = np.random.default_rng(1)
    for k in range(100):
        if k % 10 == 0:
            out = monitor.update(k, math.nan if k % 20 else 'abc', 0.0, 0.0, fail_safe=True)
        else:
            out = monitor.update(k, rng.standard_normal(), 0.0, rng.standard_normal())
    assert out is not None and monitor.nonfinite_samples == 10
    assert out['samples'] == 90 and out['fail_safe_pct'] == pytest.approx(10.0)
    assert out['verdict'] == 'fail-safe output 10 % of the time' and out['time'] == 99.0
    json.dumps(out, allow_nan=False)


def test_hagglund_load_disturbances_of_a_sine_against_the_half_wave_iae() -> None:
    """[Hagglund1995]: a half-wave of A·sin(2πt/P) has IAE A·P/π; with Ti the limit 2a/ω_u is
    a·Ti/π. Above it every whole half-wave counts, below none; white noise's short half-waves
    never count."""
    ts, period, amplitude, ti = 0.1, 20.0, 1.0, 10.0
    t = np.arange(0.0, 5000.0, ts) + ts / 2          # 10·T_sup; no sample on a crossing
    e = amplitude * np.sin(2 * np.pi * t / period)
    half_waves = int(t[-1] // (period / 2))          # whole half-waves after the first
    counted = ix.load_disturbances(e, ts, amplitude=1.0, ti=ti)   # limit 3.18 < IAE 6.37
    assert counted['count'] == half_waves - 1 and counted['detected']
    # the forgetting counter: 2 per period, γ per sample over 50·Ti: about 1/(1 − γ^(P/2/ts))
    gamma = 1 - ts / (50 * ti)
    assert counted['rate'] == pytest.approx(1 / (1 - gamma ** (period / 2 / ts)), rel=0.1)
    assert ix.load_disturbances(e, ts, amplitude=3.0, ti=ti)['count'] == 0     # limit 9.5
    noise = 0.1 * np.random.default_rng(0).standard_normal(t.size)
    assert ix.load_disturbances(noise, ts, amplitude=0.1, ti=ti)['count'] == 0
    assert ix.load_disturbances(e, ts, amplitude=0.0, ti=ti) == {
        'count': None, 'rate': None, 'detected': False}


def test_saturation_counts_the_samples_at_a_real_limit_only():
    """A limit of 1e12 is the parameters' "none": it neither counts nor widens the tolerance
    (a tolerance relative to a 1e12 span once called every sample within 1e6 "saturated")."""
    from tank_control.core.monitoring.indices import saturation_pct
    u = np.array([1.0, -0.4, 0.5, 1.0 - 1e-7])
    assert saturation_pct(u, -1e12, 1.0) == 50.0              # 1.0 and 1.0 − 1e-7
    assert saturation_pct(u, -0.4, 1e12) == 25.0
    assert saturation_pct(u, -1e12, 1e12) is None


def test_a_live_loop_s_start_up_response_is_not_judged_as_regulation():
    """A loop that starts at y = 0 with its setpoint at 100 rises smoothly (a first-order
    response, 30-s time constant): until ``monitor.settle_time`` has passed since the start the
    live verdict is "no data", not "retune (sluggish …)" (the walk-through saw Harris 0.00 at
    t = 22 s); offline data (a running loop's) keeps its start."""
    from tank_control.core.monitoring.assess import LoopMonitor, MonitorConfig, assess
    config = MonitorConfig(window=600.0, period=10.0, settle_time=60.0)
    monitor = LoopMonitor(0.1, config)
    verdicts = []
    for k in range(500):                       # 50 s
        t = 0.1 * k
        s = monitor.update(t, 100.0 * (1.0 - math.exp(-t / 30.0)), 100.0, 1.0)
        if s is not None:
            verdicts.append(s['verdict'])
    assert verdicts and set(verdicts) == {'no data'}, verdicts
    t = np.arange(500) * 0.1
    offline = assess(t, 100.0 * (1.0 - np.exp(-t / 30.0)), np.full(500, 100.0), np.ones(500),
                     0.1, config)
    assert offline['regulation_samples'] == 500               # the record's start is kept
