"""Step metrics against closed forms of first- and second-order responses."""
from __future__ import annotations

import math

import numpy as np
import pytest

from scipy.optimize import brentq

from tank_control.core.analysis.step_metrics import deviation_metrics, iae, ise, step_metrics

TAU = 2.0
T = np.linspace(0.0, 40.0, 40001)


def first_order(t, y0=0.0, r=1.0):
    return y0 + (r - y0) * (1 - np.exp(-t / TAU))


def second_order(t, zeta, wn=1.0):
    wd = wn * math.sqrt(1 - zeta ** 2)
    phi = math.acos(zeta)
    return 1 - np.exp(-zeta * wn * t) * np.sin(wd * t + phi) / math.sqrt(1 - zeta ** 2)


def test_first_order_rise_and_settling_times():
    m = step_metrics(T, first_order(T), r_final=1.0)
    assert m.overshoot == 0.0
    assert m.rise_time == pytest.approx(TAU * math.log(9.0), rel=1e-4)       # 10 → 90 %
    assert m.settling_time == pytest.approx(TAU * math.log(50.0), rel=1e-3)  # 2 % band
    assert abs(m.steady_state_error) < 1e-6


@pytest.mark.parametrize('zeta', [0.2, 0.5, 0.7])
def test_second_order_overshoot(zeta):
    m = step_metrics(T, second_order(T, zeta), r_final=1.0)
    assert m.overshoot == pytest.approx(100 * math.exp(-math.pi * zeta / math.sqrt(1 - zeta ** 2)), rel=1e-4)
    assert m.peak_time == pytest.approx(math.pi / math.sqrt(1 - zeta ** 2), abs=2e-3)


def test_downward_step_and_offset_start():
    """A step from 50 down to 30 gives the same times as the normalised up-step."""
    y = first_order(T, y0=50.0, r=30.0)
    m = step_metrics(T + 10.0, y, r_final=30.0, t_step=10.0)
    assert m.rise_time == pytest.approx(TAU * math.log(9.0), rel=1e-4)
    assert m.settling_time == pytest.approx(TAU * math.log(50.0), rel=1e-3)
    y2 = 50.0 - 20.0 * second_order(T, 0.5)
    assert step_metrics(T, y2, r_final=30.0).overshoot == pytest.approx(16.303, rel=1e-3)


def test_noisy_response_is_measured_robustly():
    rng = np.random.default_rng(1)
    y = first_order(T) + rng.normal(0.0, 0.003, T.size)
    m = step_metrics(T, y, r_final=1.0)
    assert m.rise_time == pytest.approx(TAU * math.log(9.0), rel=0.02)
    assert m.overshoot < 2.0
    # settling is read on the raw record: noise of band/20 moves it by little
    y = first_order(T) + rng.normal(0.0, 0.001, T.size)
    assert step_metrics(T, y, r_final=1.0).settling_time == pytest.approx(TAU * math.log(50.0), rel=0.1)
    assert abs(m.steady_state_error) < 0.002


def test_steady_state_error_and_unsettled_response():
    assert step_metrics(T, 0.9 * first_order(T), r_final=1.0).steady_state_error == pytest.approx(0.1, abs=1e-6)
    sustained = 1 + 0.5 * np.sin(T)
    m = step_metrics(T, np.where(T > 0, sustained, 0.0), r_final=1.0, y0=0.0)
    assert math.isnan(m.settling_time)
    assert math.isnan(step_metrics(T, 0.5 * first_order(T), r_final=1.0).rise_time)


def test_error_integrals():
    e = np.exp(-T / TAU)
    assert iae(T, e) == pytest.approx(TAU, rel=1e-6)
    assert iae(T, -e) == pytest.approx(TAU, rel=1e-6)
    assert ise(T, e) == pytest.approx(TAU / 2, rel=1e-6)


def test_deviation_metrics_of_a_load_bump_match_closed_forms():
    """e(t) = −A·(t/τ)·e^(1 − t/τ): peak −A at t = τ, ∫e dt = −A·e·τ, and |e| stays within
    2 % of A after the root x > 1 of x·e^(1 − x) = 0.02 (x = t/τ)."""
    amp, tau = 0.7, 3.0
    t = np.linspace(0.0, 100.0, 200001)
    e = -amp * (t / tau) * np.exp(1 - t / tau)
    m = deviation_metrics(t, e)
    assert m.peak_error == pytest.approx(amp, rel=1e-9)
    assert m.peak_signed == pytest.approx(-amp, rel=1e-9)
    assert m.peak_time == pytest.approx(tau, abs=1e-3)
    assert m.iae == pytest.approx(amp * math.e * tau, rel=1e-6)
    assert m.integral_error == pytest.approx(-amp * math.e * tau, rel=1e-6)
    x = brentq(lambda x: x * math.exp(1 - x) - 0.02, 1.0, 50.0)
    assert m.recovery_time == pytest.approx(x * tau, abs=1e-3)
    assert abs(m.final_error) < 1e-9 and m.initial_error == 0.0


def test_deviation_metrics_without_recovery_and_without_deviation():
    assert math.isnan(deviation_metrics(T, 0.5 * np.sin(T)).recovery_time)     # still swinging
    still = deviation_metrics(T, np.zeros_like(T))
    assert (still.peak_error, still.iae, still.recovery_time) == (0.0, 0.0, 0.0)
    offset = deviation_metrics(T, np.full_like(T, 0.3))
    assert offset.final_error == pytest.approx(0.3) and offset.initial_error == 0.3


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match='r_final'):
        step_metrics(T, first_order(T), r_final=0.0)
    with pytest.raises(ValueError, match='t'):
        iae([0.0, 0.0, 1.0], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match='samples'):
        ise(T, np.ones(3))
