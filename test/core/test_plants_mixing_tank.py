"""The nonlinear mixing tank of [Michalski2021] §1 ([Michalski2021] §1): steady state, delays, physics, linear model."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.interfaces import Plant
from tank_control.core.plants.mixing_tank import MixingTank, MixingTankConfig

U0 = [14.0, 37.0]                      # F_H, F_Cin at [Michalski2021]'s operating point [cm³/s]
D0 = [12.0, 33.0, 62.0, 23.0]          # F_D, T_D, T_H, T_C
T_SS = (14 * 62 + 37 * 23 + 12 * 33) / 63          # = 2115/63, the steady temperature


def _tank(**changes) -> MixingTank:
    return MixingTank(MixingTankConfig(**changes))


def test_tank_satisfies_the_protocol():
    tank = MixingTank()
    assert isinstance(tank, Plant)
    assert tank.output_names == ('h', 'T_out') and tank.input_names == ('F_H', 'F_Cin')
    assert tank.disturbance_names == ('F_D', 'T_D', 'T_H', 'T_C')


def test_operating_point_is_a_steady_state():
    # [Michalski2021] §1: outflow 7·√81 = 63 = 14 + 37 + 12 and T = 2115/63, so dh/dt = dT/dt = 0.
    tank = MixingTank()
    np.testing.assert_allclose(tank.outputs(), [81.0, T_SS], rtol=0, atol=1e-12)
    for _ in range(600):
        tank.step(U0, D0, 1.0)
    np.testing.assert_allclose(tank.outputs(), [81.0, T_SS], rtol=0, atol=1e-10)
    np.testing.assert_allclose(tank.state, [0.7 * 81 ** 2, T_SS], rtol=1e-13)
    status = tank.status
    assert status['F_out'] == pytest.approx(63.0, rel=1e-13)
    assert status['clipped_flows'] == 0 and not status['overflow'] and not status['empty']


def test_cold_inflow_reaches_the_tank_after_tau_cold():
    tank = MixingTank()
    levels = []
    for _ in range(200):
        tank.step([14.0, 45.0], D0, 1.0)           # +8 cm³/s of cold water from t = 0
        levels.append(tank.outputs()[0])
    levels = np.array(levels)                      # levels[k] is h at t = k + 1
    np.testing.assert_allclose(levels[:180], 81.0, rtol=0, atol=1e-11)   # up to t = 180
    assert levels[180] - 81.0 > 0.05                # visible one second later


def test_cold_inflow_delay_need_not_be_a_multiple_of_the_sample_time():
    # τ_C = 180.37 s: the extra 8 cm³/s flows for the last 0.63 s of [180, 181).
    tank = _tank(tau_cold=180.37)
    for _ in range(181):
        tank.step([14.0, 45.0], D0, 1.0)
        if tank.time == 180.0:
            assert tank.state[0] == pytest.approx(0.7 * 81 ** 2, abs=1e-9)
    V0, tau = 0.7 * 81 ** 2, 0.63
    lam = 63.0 / (4 * V0)                          # linearised outflow rate dF/dV
    dV = 8.0 * (1 - math.exp(-lam * tau)) / lam    # exact for the linearised outflow
    assert tank.state[0] - V0 == pytest.approx(dV, rel=1e-6)


def test_outlet_temperature_is_the_tank_temperature_tau_seconds_earlier():
    tank = MixingTank()
    inside, outlet = [tank.state[1]], [tank.outputs()[1]]
    for _ in range(300):
        tank.step([20.0, 37.0], D0, 1.0)           # more hot water from t = 0
        inside.append(tank.state[1])
        outlet.append(tank.outputs()[1])
    inside, outlet = np.array(inside), np.array(outlet)
    assert inside[10] > T_SS + 0.1                  # T reacts at once ...
    np.testing.assert_allclose(outlet[:121], T_SS, rtol=0, atol=1e-12)   # ... T_out after 120 s
    np.testing.assert_allclose(outlet[120:], inside[:-120], rtol=0, atol=1e-12)


def test_outlet_delay_between_grid_points_is_interpolated_accurately():
    coarse = _tank(tau_out=120.05)                 # 0.05 s is half the RK4 step
    fine = _tank(tau_out=0.0, integration_step=0.05)
    for k in range(150):
        coarse.step([20.0, 37.0], D0, 1.0)
    inside = {}
    for k in range(100 * 20):
        fine.step([20.0, 37.0], D0, 0.05)
        inside[k + 1] = fine.state[1]
    assert coarse.outputs()[1] == pytest.approx(inside[(150 * 20) - (120 * 20) - 1], abs=1e-9)


def test_negative_flows_are_clipped_to_zero_and_counted():
    clipped, reference = MixingTank(), MixingTank()
    for _ in range(10):
        clipped.step([-5.0, 37.0], [-1.0, 33.0, 62.0, 23.0], 1.0)
        reference.step([0.0, 37.0], [0.0, 33.0, 62.0, 23.0], 1.0)
    np.testing.assert_array_equal(clipped.outputs(), reference.outputs())
    status = clipped.status
    assert status['clipped_F_H'] == 10 and status['clipped_F_D'] == 10
    assert status['clipped_F_Cin'] == 0 and status['clipped_flows'] == 20


def test_inflow_temperatures_are_kept_physical():
    tank = _tank(tau_out=0.0)
    for _ in range(20):
        tank.step(U0, [12.0, 33.0, 150.0, -10.0], 1.0)
    status = tank.status
    assert status['clipped_T_H'] == 20 and status['clipped_T_C'] == 20
    assert 0.0 <= tank.outputs()[1] <= 100.0


def test_draining_tank_follows_the_closed_form_and_never_goes_below_zero():
    # No inflow: dh/dt = −α/(2C)·h^(−1/2) ⇒ h^(3/2) = h0^(3/2) − 3α·t/(4C); empty at 97.2 s.
    tank = _tank(tau_cold=0.0, tau_out=0.0)
    T_start = tank.state[1]
    for k in range(1, 121):
        tank.step([0.0, 0.0], [0.0, 33.0, 62.0, 23.0], 1.0)
        h = tank.outputs()[0]
        closed = max(81.0 ** 1.5 - 3 * 7.0 * k / (4 * 0.7), 0.0) ** (2 / 3)
        if k <= 95:
            assert h == pytest.approx(closed, rel=1e-6), k
        assert h >= 0.0
        assert tank.state[1] == T_start            # no inflow: temperature unchanged
    assert h == 0.0 and tank.status['empty'] and tank.status['F_out'] == 0.0


def test_refilling_an_empty_tank_with_hot_water_gives_hot_water():
    tank = _tank(tau_cold=0.0, tau_out=0.0, initial_h=0.0)
    for _ in range(30):
        tank.step([20.0, 0.0], [0.0, 33.0, 62.0, 23.0], 1.0)
        assert np.all(np.isfinite(tank.outputs()))
        assert T_SS - 1e-12 <= tank.state[1] <= 62.0 + 1e-12
    assert tank.state[1] == pytest.approx(62.0, abs=1e-9)
    assert tank.outputs()[0] > 0.0 and tank.status['stiff_substeps'] > 0


def test_overflow_spills_above_h_max():
    tank = _tank(h_max=85.0, tau_cold=0.0)
    for _ in range(200):
        tank.step([100.0, 37.0], D0, 1.0)
    assert tank.outputs()[0] == pytest.approx(85.0, abs=1e-12)
    status = tank.status
    assert status['overflow'] and status['overflow_steps'] > 0
    spilled = status['spilled_volume']
    for _ in range(10):                            # at the brim: spill = inflow − α·√h_max
        tank.step([100.0, 37.0], D0, 1.0)
    assert tank.status['spilled_volume'] - spilled == pytest.approx(
        10 * (100 + 37 + 12 - 7 * math.sqrt(85.0)), rel=1e-9)


def test_linearize_reproduces_the_documents_matrices():
    # [Michalski2021] eq. 6 / [Michalski2021] §1, compared at the printed number of significant digits.
    A, B, C, D = MixingTank().linearize(1.0)
    printed_A = [[0.9966, 0.0], [-4.23e-09, 0.9864]]
    printed_B = [[0.9983, 0.9983, 0.9983, 0, 0, 0],
                 [0.006148, -0.002286, -0.0001233, 0.003028, 0.008001, 0.002595]]

    def rounded(value, like):
        if like == 0:
            return 0.0 if abs(value) < 1e-15 else value
        digits = len(f'{abs(like):.6e}'.split('e')[0].rstrip('0').replace('.', ''))
        return float(f'{value:.{digits - 1}e}')

    for got, want in ((A, printed_A), (B, printed_B)):
        for g, w in zip(np.ravel(got), np.ravel(want)):
            assert rounded(g, w) == pytest.approx(w, rel=1e-12), (g, w)
    np.testing.assert_array_equal(C, np.eye(2))
    np.testing.assert_array_equal(D, np.zeros((2, 6)))


def test_linear_model_predicts_small_deviations_of_the_nonlinear_tank():
    # Without delays, from the operating point, one sample of a small input change.
    ts, delta = 1.0, 1e-3
    base = _tank(tau_cold=0.0, tau_out=0.0, initial_T=33.57, T_op=33.57)
    A, B, _, _ = base.linearize(ts)
    u0 = np.array([14.0, 37.0, 12.0, 62.0, 23.0, 33.0])     # model order: F_H F_C F_D T_H T_C T_D
    x0 = base.state
    base.step(u0[:2], [u0[2], u0[5], u0[3], u0[4]], ts)
    for i in range(6):
        u = u0.copy()
        u[i] += delta
        tank = _tank(tau_cold=0.0, tau_out=0.0, initial_T=33.57, T_op=33.57)
        tank.step(u[:2], [u[2], u[5], u[3], u[4]], ts)
        sensitivity = (tank.state - base.state) / delta
        np.testing.assert_allclose(sensitivity, B[:, i], rtol=1e-3, atol=1e-9)
    assert np.all(np.isfinite(A)) and x0[0] == pytest.approx(0.7 * 81 ** 2)


def test_results_do_not_depend_on_the_sample_time_beyond_rk4_accuracy():
    one, tenth = MixingTank(), MixingTank()
    for _ in range(250):
        one.step([18.0, 30.0], D0, 1.0)
    for _ in range(2500):
        tenth.step([18.0, 30.0], D0, 0.1)
    np.testing.assert_allclose(one.outputs(), tenth.outputs(), rtol=1e-11)


@pytest.mark.parametrize('changes, words', [
    ({'tau_cold': 700.0}, 'tau_cold: 700 is above max_dead_time'),
    ({'C': -1.0}, 'C: -1 is below the minimum'),
    ({'integration_step': 0.0}, 'integration_step: 0 is below the minimum'),
    ({'max_dead_time': 900.0}, 'max_dead_time: read-only'),
    ({'h_max': 50.0}, 'initial_h: 81 is above h_max'),
])
def test_bad_configuration_is_rejected(changes, words):
    tank = MixingTank()
    before = tank.config
    with pytest.raises(ValueError, match=words):
        tank.configure(**changes)
    assert tank.config == before


def test_live_delay_change_uses_the_stored_history():
    tank = MixingTank()
    outlet = []
    for k in range(200):
        if k == 150:
            tank.configure(tau_out=140.0)         # reads 20 s further back from now on
        tank.step([20.0, 37.0], D0, 1.0)
        outlet.append(tank.outputs()[1])
    inside = MixingTank(MixingTankConfig(tau_out=0.0))
    record = [inside.state[1]]
    for _ in range(200):
        inside.step([20.0, 37.0], D0, 1.0)
        record.append(inside.state[1])
    assert outlet[-1] == pytest.approx(record[200 - 140], abs=1e-12)


def test_bad_step_input_is_rejected():
    tank = MixingTank()
    with pytest.raises(ValueError, match='u: non-finite'):
        tank.step([float('nan'), 37.0], D0, 1.0)
    with pytest.raises(ValueError, match='d: 3 values given, expected 4'):
        tank.step(U0, D0[:3], 1.0)
    assert tank.status['steps'] == 0
