"""Measured-disturbance feedforward of the two-loop PI (core/control/feedforward.py), checked on
the nonlinear tank of [Michalski2021] §1 (core/plants/mixing_tank.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.control.feedforward import DisturbanceFeedforward, FeedforwardConfig
from tank_control.core.control.kinds import registry
from tank_control.core.plants.mixing_tank import MixingTank, MixingTankConfig

T0 = 2115.0 / 63.0                                    # operating-point temperature [°C] ([Michalski2021] §1)
D_NEW = (15.0, 40.0)                                  # F_D [cm³/s], T_D [°C]: both changed


def _tank(**changes) -> MixingTank:
    return MixingTank(MixingTankConfig(integration_step=0.5, **changes))


@pytest.mark.parametrize('h0, t0', [(81.0, T0), (40.0, 30.0), (150.0, 40.0)])
def test_static_feedforward_keeps_the_nonlinear_tank_at_its_steady_state(h0, t0):
    """At any steady state (h0, t0) the flows plus the static feedforward of a new (F_D, T_D)
    hold the nonlinear tank there: the balances are exact (no linearisation)."""
    from tank_control.core.control.scheduling import steady_flows
    f_h, f_c = steady_flows(h0, t0)
    tank = _tank(F_C=f_c, initial_h=h0, initial_T=t0, tau_cold=0.0, tau_out=0.0)
    ff = DisturbanceFeedforward(FeedforwardConfig(mode='static'), 1.0)
    d_hot, d_cold = ff.static(*D_NEW)
    for _ in range(4000):
        tank.step([f_h + d_hot, f_c + d_cold], [*D_NEW, 62.0, 23.0], 1.0)
    h, temp = tank.outputs()
    assert abs(h - h0) < 1e-9 and abs(temp - t0) < 1e-9
    # and without it the tank moves away
    tank = _tank(F_C=f_c, initial_h=h0, initial_T=t0, tau_cold=0.0, tau_out=0.0)
    for _ in range(4000):
        tank.step([f_h, f_c], [*D_NEW, 62.0, 23.0], 1.0)
    assert abs(tank.outputs()[0] - h0) > 1.0


def test_dynamic_feedforward_keeps_the_temperature_through_the_cold_delay():
    """With τ_C = 180 s the cold part arrives late: the static feedforward upsets T for τ_C,
    the dynamic one bridges it with the hot flow (heat balance kept: T stays exactly) and
    equals the static one once the cold part has arrived. The step: F_D 12 → 15 cm³/s at
    33 °C (tank_pi_disturbance.yaml), mostly a cold-flow correction."""
    step = (15.0, 33.0)
    runs = {}
    for mode in ('static', 'dynamic'):
        tank = _tank()
        ff = DisturbanceFeedforward(FeedforwardConfig(mode=mode), 1.0)
        ff.settle(np.array([12.0, 33.0]))
        temps, flows = [], []
        for k in range(1200):
            d = np.array(step if k >= 10 else (12.0, 33.0))
            d_hot, d_cold = ff.step(d, T0)
            flows.append((d_hot, d_cold))
            tank.step([14.0 + d_hot, 37.0 + d_cold], [*d, 62.0, 23.0], 1.0)
            temps.append(tank.state[1])
        runs[mode] = (np.array(temps), np.array(flows))
    static_t, static_u = runs['static']
    dynamic_t, dynamic_u = runs['dynamic']
    assert np.max(np.abs(dynamic_t - T0)) < 1e-9
    assert np.max(np.abs(static_t - T0)) > 0.3
    assert np.array_equal(static_u[:, 1], dynamic_u[:, 1])        # cold part: sent at once
    np.testing.assert_allclose(dynamic_u[10 + 180:, 0], static_u[10 + 180:, 0], atol=1e-12)
    assert np.all(np.abs(dynamic_u[10:10 + 180, 0] - static_u[10:10 + 180, 0]) > 0.1)
    # the level settles back after the window: total inflow correct from then on
    assert abs(math.fsum(dynamic_u[-1]) + (step[0] - 12.0)) < 1e-12


def test_nominal_or_unmeasured_disturbance_gives_no_feedforward():
    ff = DisturbanceFeedforward(FeedforwardConfig(mode='dynamic'), 1.0)
    assert ff.step(np.array([12.0, 33.0]), T0) == (0.0, 0.0)
    assert ff.step(np.array([math.nan, math.nan]), T0) == (0.0, 0.0)
    assert ff.step(np.array([]), T0) == (0.0, 0.0)


def _closed_loop(mode: str, t_end: int = 6000) -> tuple[MixingTank, object, list]:
    ctl = registry.make_controller('two_loop_pi', {'two_loop.feedforward': mode})
    tank = _tank()
    ctl.reset(tank.outputs(), np.array([14.0, 37.0]))
    integrals = []
    r = np.array([81.0, T0])
    for k in range(t_end):
        d = np.array(D_NEW if k >= 100 else (12.0, 33.0))
        u = ctl.step(float(k), tank.outputs(), r, d)
        tank.step(u, [*d, 62.0, 23.0], 1.0)
        integrals.append((ctl.status['i.h'], ctl.status['i.T_out']))
    return tank, ctl, integrals


@pytest.mark.parametrize('mode', ['static', 'dynamic'])
def test_in_the_loop_the_feedforward_carries_the_whole_correction(mode):
    """Closed loop ([Michalski2021]'s gains) on the nonlinear tank: after the disturbance step the PI
    integrals return to their values before it — the feedforward holds the new steady state
    alone — while without feedforward they must move to carry it."""
    _, ctl, integrals = _closed_loop(mode)
    assert ctl.disturbance_names == ('F_D', 'T_D')
    before, after = np.array(integrals[99]), np.array(integrals[-1])
    np.testing.assert_allclose(after, before, atol=2e-3)
    _, _, plain = _closed_loop('none')
    assert np.max(np.abs(np.array(plain[-1]) - np.array(plain[99]))) > 1.0


def test_take_over_with_feedforward_is_bumpless():
    """reset(y, u) at a non-nominal disturbance: the first step returns u (the integrals take
    u minus the feedforward)."""
    ctl = registry.make_controller('two_loop_pi', {'two_loop.feedforward': 'dynamic'})
    ctl.reset(np.array([80.0, 34.0]), np.array([20.0, 40.0]))
    u = ctl.step(0.0, np.array([80.0, 34.0]), np.array([85.0, 33.0]), np.array(D_NEW))
    assert u == pytest.approx([20.0, 40.0], abs=1e-12)
    assert ctl.status['ff.F_Cin'] != 0.0


def test_dynamic_feedforward_predicts_the_level_excursion_it_causes():
    """Open loop on the nonlinear tank (flows at the operating point plus the dynamic
    feedforward, F_D 12 → 15 cm³/s): over the τ_C window the mass imbalance raises the level;
    the predicted ``level_offset`` (the linearised level of [Michalski2021] eq. 4) follows the tank's level
    to within 2 % of the excursion, and both return to 0 once the cold part has arrived."""
    tank = _tank()
    ff = DisturbanceFeedforward(FeedforwardConfig(mode='dynamic'), 1.0)
    ff.settle(np.array([12.0, 33.0]))
    predicted, actual = [], []
    for k in range(3000):
        d = np.array((15.0, 33.0) if k >= 10 else (12.0, 33.0))
        d_hot, d_cold = ff.step(d, T0, 81.0)
        predicted.append(ff.level_offset)
        actual.append(tank.outputs()[0] - 81.0)
        tank.step([14.0 + d_hot, 37.0 + d_cold], [*d, 62.0, 23.0], 1.0)
    predicted, actual = np.array(predicted), np.array(actual)
    peak = np.max(actual)
    assert 3.0 < peak < 4.0                                           # cm, over ~180 s
    assert np.max(np.abs(predicted - actual)) < 0.02 * peak
    assert abs(actual[-1]) < 0.01 and abs(predicted[-1]) < 0.01
