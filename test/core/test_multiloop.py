"""Two-loop PI for the mixing tank ([Michalski2021] §2–3, [Michalski2021] §2–3)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from tank_control.core.control.kinds import two_loop_pi
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.multiloop import (
    D21_DEN,
    D21_NUM,
    D21Filter,
    TwoLoopPi,
    document_config,
)
from tank_control.core.interfaces import Controller
from tank_control.core.params import ConfigError

C, ALPHA, TC, TH, TD = 0.7, 7.0, 23.0, 62.0, 33.0      # [Michalski2021] §1
T0 = 2115.0 / 63.0                                    # operating-point temperature 33.571 °C


def tank_run(ctl, r_fn, t_end: int, fd: float = 12.0) -> np.ndarray:
    """Nonlinear tank of [Michalski2021] §1 (Euler, 0.5 s steps) with 180 s delay on F_C and 120 s on
    T_out, controller at 1 s, started at the operating point. Rows: h, T_out, F_H, F_Cin, F_C."""
    vol, temp = C * 81.0 ** 2, T0
    fc_line, t_line = [37.0] * 180, [T0] * 120
    ctl.reset(np.array([81.0, T0]), np.array([14.0, 37.0]))
    out = np.empty((t_end, 5))
    for k in range(t_end):
        h, tout = math.sqrt(vol / C), t_line[k % 120]
        u = ctl.step(float(k), np.array([h, tout]), r_fn(k), np.array([]))
        fc = fc_line[k % 180]
        fc_line[k % 180] = u[1]
        fin = u[0] + fc + fd
        for _ in range(2):
            d_vol = fin - ALPHA * (vol / C) ** 0.25
            d_temp = (u[0] * TH + fc * TC + fd * TD - fin * temp) / vol
            vol, temp = vol + 0.5 * d_vol, temp + 0.5 * d_temp
        t_line[k % 120] = temp
        out[k] = (h, tout, u[0], u[1], fc)
    return out


def steps(k: int) -> np.ndarray:
    """h: 81 → 85 cm at 100 s; T_out: 33.57 → 35 °C at 2500 s."""
    return np.array([81.0 if k < 100 else 85.0, T0 if k < 2500 else 35.0])


def _physical(out: np.ndarray) -> None:
    assert np.all(out[:, 0] > 0)
    assert np.all((out[:, 2:4] >= 0) & (out[:, 2:4] <= 300))


def test_without_decoupling_tracks_both_setpoints_and_shows_coupling():
    ctl = TwoLoopPi(document_config('none'))
    out = tank_run(ctl, steps, 5000)
    _physical(out)
    assert abs(out[2499, 0] - 85.0) < 0.05
    assert abs(out[-1, 1] - 35.0) < 0.05
    assert np.abs(out[100:2500, 1] - T0).max() > 0.5     # [Michalski2021]: a level step disturbs T visibly


def test_with_decoupling_reduces_the_interaction():
    out = tank_run(TwoLoopPi(document_config('dynamic')), steps, 5000)
    _physical(out)
    assert abs(out[2499, 0] - 85.0) < 0.3
    assert np.abs(out[100:2500, 1] - T0).max() < 0.3     # was > 0.5 without decoupling
    assert abs(out[-1, 1] - 35.0) < 0.5 and abs(out[-1, 0] - 85.0) < 0.5


def test_static_and_dynamic_d21_behave_alike():
    """[Michalski2021] §3: 'the differences were unnoticeable'."""
    a = tank_run(TwoLoopPi(document_config('static')), steps, 1500)
    b = tank_run(TwoLoopPi(document_config('dynamic')), steps, 1500)
    assert np.abs(a[:, :2] - b[:, :2]).max() < 0.05


def test_d21_filter_is_eq_2_and_its_gain_is_2_69():
    assert D21Filter.dc_gain() == pytest.approx(2.69, abs=5e-3)
    assert (TH - T0) / (T0 - TC) == pytest.approx(2.69, abs=5e-3)    # heat-balance decoupling gain
    x = np.sin(0.3 * np.arange(50)) + 1.0
    f = D21Filter()
    ours = [f.step(v) for v in x]
    assert np.allclose(ours, lfilter(D21_NUM, D21_DEN, x), rtol=1e-12, atol=1e-12)


def test_static_decoupler_sums_and_saturates_after_the_sum():
    ctl = TwoLoopPi(document_config('static'))
    ctl.reset(np.array([81.0, T0]), np.array([14.0, 37.0]))
    u = ctl.step(0.0, np.array([81.0, T0]), np.array([81.0, T0]), np.array([]))
    assert u == pytest.approx([14.0, 37.0], abs=1e-9)
    st = ctl.status
    v_h, v_t = st['v.h'], st['v.T_out']
    assert u == pytest.approx([v_h - v_t, v_t + 2.69 * v_h], abs=1e-9)
    assert v_t < 0          # the T loop's output is negative here; only the sum is limited to ≥ 0
    # drive the level far below the setpoint range: F_H must clip at 0, integral must not wind up
    for k in range(1, 2000):
        u = ctl.step(float(k), np.array([200.0, T0]), np.array([81.0, T0]), np.array([]))
        assert u[0] >= 0.0 and u[1] >= 0.0
    assert u[0] == 0.0 and ctl.status['saturated.F_H'] and ctl.status['anti_windup_active']
    i_wound = ctl.status['i.h']
    for k in range(2000, 2100):
        u = ctl.step(float(k), np.array([200.0, T0]), np.array([81.0, T0]), np.array([]))
    assert ctl.status['i.h'] == pytest.approx(i_wound, abs=1.0)    # bounded, not growing


def test_anti_windup_speeds_recovery_from_saturation():
    """A long period with F_H saturated at 0 (level far too high) then back to normal."""
    def run(method):
        ctl = TwoLoopPi(document_config('none', anti_windup=method))
        ctl.reset(np.array([81.0, T0]), np.array([14.0, 37.0]))
        for k in range(1000):
            ctl.step(float(k), np.array([150.0, T0]), np.array([81.0, T0]), np.array([]))
        u = ctl.step(1000.0, np.array([77.0, T0]), np.array([81.0, T0]), np.array([]))
        return u[0]                           # level now 4 cm below the setpoint
    assert run('none') == 0.0                 # wound-up integral (about -690) keeps F_H shut
    assert run('back_calculation') >= 0.9 * 4.0 - 0.1     # integral tracked the limit: P acts at once
    assert run('conditional_integration') >= 0.9 * 4.0 - 0.1


@pytest.mark.parametrize('decoupling', ['none', 'static', 'dynamic'])
def test_reset_is_bumpless(decoupling):
    """After reset(y, u) the first step returns u, whatever the setpoint."""
    ctl = TwoLoopPi(document_config(decoupling))
    ctl.reset(np.array([80.0, 34.0]), np.array([20.0, 40.0]))
    u = ctl.step(0.0, np.array([80.0, 34.0]), np.array([85.0, 33.0]), np.array([]))
    assert u == pytest.approx([20.0, 40.0], abs=1e-9)
    u = ctl.step(1.0, np.array([80.0, 34.0]), np.array([85.0, 33.0]), np.array([]))
    assert np.all(np.abs(u - [20.0, 40.0]) < 1.0)          # then moves gradually


def test_non_finite_measurement_holds_the_flows():
    ctl = TwoLoopPi()
    ctl.reset(np.array([81.0, T0]), np.array([14.0, 37.0]))
    u0 = ctl.step(0.0, np.array([81.0, T0]), np.array([82.0, T0]), np.array([]))
    u1 = ctl.step(1.0, np.array([math.nan, T0]), np.array([82.0, T0]), np.array([]))
    assert np.array_equal(u0, u1) and ctl.status['input_fault']
    u2 = ctl.step(2.0, np.array([81.0, T0]), np.array([82.0, T0]), np.array([]))
    assert np.all(np.isfinite(u2)) and abs(u2[0] - u0[0]) < 0.1


def test_protocol_params_and_validation():
    ctl = TwoLoopPi()
    assert isinstance(ctl, Controller)
    assert ctl.output_names == ('h', 'T_out') and ctl.input_names == ('F_H', 'F_Cin')
    kind = two_loop_pi.KIND
    for spec in kind.specs():
        assert spec.description and spec.check(spec.default) is None

    def reason(values: dict) -> str:
        with pytest.raises(ConfigError) as info:
            resolve(kind, values)
        return str(info.value)

    assert resolve(kind, {}).config == document_config('none')
    assert reason({'u_min': 300.0, 'u_max': 100.0}).startswith('u_min')
    assert reason({'two_loop.kp_T': 0.2}).startswith('two_loop.ki_T: ')   # named by parameter
    assert reason({'fail_safe_output': [14.0, 400.0]}).startswith('fail_safe_output')
    assert resolve(kind, {'two_loop.decoupling': 'dynamic'}).config.decoupling == 'dynamic'
    with pytest.raises(ValueError, match='decoupling'):
        TwoLoopPi(document_config('sideways'))


def test_setpoint_guard_prevents_the_unreachable_temperature_failure_of_003():
    """[Michalski2021] §2.2: T_out setpoint near T_C with the warmer disturbance inflow is unreachable; the
    integrators then keep F_Cin up and the level drifts. The guard limits r_T to the reachable
    steady-state interval at the level setpoint: ((F − F_D)·T_C + F_D·T_D)/F + margin."""
    r_fn = lambda k: np.array([81.0, T0 if k < 100 else 24.0])      # noqa: E731
    guarded = TwoLoopPi(document_config('none'))
    out = tank_run(guarded, r_fn, 3000)
    reachable = (51.0 * TC + 12.0 * TD) / 63.0 + 0.5                  # 25.40 °C at h = 81 cm
    assert guarded.status['setpoint_limited'] and guarded.status['r.T_out'] == pytest.approx(reachable)
    assert abs(out[-1, 0] - 81.0) < 0.2 and abs(out[-1, 1] - reachable) < 0.1
    unguarded = TwoLoopPi(document_config('none', setpoint_guard=False))
    out = tank_run(unguarded, r_fn, 3000)
    assert out[-1, 0] - 81.0 > 3.0 and out[-1, 2] == 0.0             # F_H shut, level drifting up


@pytest.mark.parametrize('method', ['conditional_integration', 'back_calculation'])
def test_decoupled_anti_windup_stays_off_while_no_flow_is_clipped(method):
    """With a decoupler, loop i's effective output is its applied flow less the decoupler's
    term; when the flow is not clipped that must be v_i itself, not (v_i + c) − c, which
    differs by rounding: conditional integration took the difference for a push into a limit
    and froze the temperature integrator (T_out stuck at its old setpoint)."""
    ctl = TwoLoopPi(document_config('dynamic', anti_windup=method))
    out = tank_run(ctl, lambda k: np.array([81.0, T0 if k < 10 else 36.0]), 3000)
    assert np.all((out[:, 2:4] > 0) & (out[:, 2:4] < 300))    # no flow ever clipped …
    assert not ctl.status['anti_windup_active']               # … so anti-windup never acts
    assert out[:, 1].max() > 36.0                             # and T_out reaches its setpoint
    active = []
    for k in range(50):
        ctl.step(3000.0 + k, np.array([81.0, 36.0]), np.array([81.0, 36.0]), np.array([]))
        active.append(ctl.status['anti_windup_active'])
    assert not any(active)
