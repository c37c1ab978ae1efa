"""The linearised mixing tank ([Michalski2021] eqs. 4–6): equilibrium, closed forms, exact delays that are
not multiples of the tick, agreement with the nonlinear tank for small moves, and no clipping."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.plants.kinds.registry import make_plant

OP_T = 2115.0 / 63.0        # the tank's steady state at [Michalski2021]'s operating point [°C]


def run(plant, steps, h=1.0, u=(14.0, 37.0), d=()):
    out = [plant.outputs()]
    for k in range(steps):
        uk = u(k * h) if callable(u) else u
        plant.step(list(uk), list(d), h)
        out.append(plant.outputs())
    return np.array(out)


def test_at_the_operating_point_nothing_moves_and_t_is_the_tank_steady_state():
    # [Michalski2021] prints T_op = 33.57; with the constant term the linear equilibrium is 2115/63.
    y = run(make_plant('mixing_tank_linear'), 500)
    np.testing.assert_allclose(y[:, 0], 81.0, atol=1e-12)
    np.testing.assert_allclose(y[:, 1], OP_T, atol=1e-12)


def test_a_hot_flow_step_moves_the_level_as_the_first_order_closed_form():
    # dV/dt = −a·(V − V_op) + ΔF with a = F(h)/(4·V) = 63/(4·0.7·81²); h = 81 + ΔV/(2·C·81).
    plant = make_plant('mixing_tank_linear', {'tau_out': 0.0})
    y = run(plant, 400, h=0.5, u=(15.0, 37.0))
    t = np.arange(401) * 0.5
    a = 63.0 / (4 * 0.7 * 81.0 ** 2)
    np.testing.assert_allclose(y[:, 0], 81.0 + (1.0 / a) * -np.expm1(-a * t) / (2 * 0.7 * 81.0),
                               rtol=0, atol=1e-11)


def test_delays_that_are_not_multiples_of_the_tick_are_exact_and_step_size_free():
    values = {'tau_cold': 180.3, 'tau_out': 120.7}
    u = lambda t: (14.0 + (t >= 5.0), 37.0 - 2.0 * (t >= 40.0))      # noqa: E731
    coarse = run(make_plant('mixing_tank_linear', values), 600, h=1.0, u=u)
    fine = run(make_plant('mixing_tank_linear', values), 2400, h=0.25,
               u=lambda t: u(math.floor(t + 1e-9)))
    np.testing.assert_allclose(coarse, fine[::4], rtol=0, atol=1e-10)


def test_t_out_is_t_delayed_by_tau_and_f_cin_acts_after_tau_c():
    plant = make_plant('mixing_tank_linear', {'tau_cold': 180.3, 'tau_out': 120.7})
    temps, t_out, levels = [], [], []
    for k in range(700):
        plant.step([14.0, 37.0 + 3.0 * (k >= 10)], [], 1.0)
        temps.append(plant.status['T'])
        t_out.append(plant.outputs()[1])
        levels.append(plant.outputs()[0])
    # F_Cin changes at t = 10 s; F_C at 190.3 s: the level is still at 81 at t = 190 s
    assert levels[189] == pytest.approx(81.0, abs=1e-12) and levels[191] > 81.0 + 1e-4
    # T_out(t) = T(t − 120.7): compare with a second plant sampled at the shifted instants
    probe = make_plant('mixing_tank_linear', {'tau_cold': 180.3, 'tau_out': 120.7})
    probe.step([14.0, 37.0], [], 10.0)
    probe.step([14.0, 40.0], [], 600.0 - 120.7 - 10.0)         # to t = 479.3 s
    assert t_out[599] == pytest.approx(probe.status['T'], abs=1e-11)    # y at t = 600 s


def test_small_moves_agree_with_the_nonlinear_tank_to_first_order():
    u = lambda t: (14.0 + 0.5 * (t >= 10.0), 37.0 + 0.5 * (t >= 800.0))   # noqa: E731
    lin = run(make_plant('mixing_tank_linear'), 3000, u=u)
    non = run(make_plant('mixing_tank', {'integration_step': 0.25}), 3000, u=u)
    dev_lin, dev_non = lin - lin[0], non - non[0]
    scale = np.max(np.abs(dev_non), axis=0)
    assert np.max(np.abs(dev_lin - dev_non), axis=0) == pytest.approx(0.0, abs=0.02 * scale.max())
    assert np.all(np.max(np.abs(dev_lin - dev_non), axis=0) < 0.02 * scale)


def test_nothing_is_clipped_the_linear_temperature_can_leave_the_physical_range():
    # [Michalski2021] §3.3: the linear model lets T fall below T_C, which no mixture can produce.
    plant = make_plant('mixing_tank_linear', {'tau_out': 0.0})
    y = run(plant, 3000, u=(0.0, 200.0))
    assert y[-1, 1] < 23.0
    tank = make_plant('mixing_tank', {'tau_out': 0.0})
    assert run(tank, 3000, u=(0.0, 200.0))[-1, 1] >= 23.0 - 1e-9


def test_a_live_change_of_the_operating_point_keeps_the_state():
    plant = make_plant('mixing_tank_linear')
    run(plant, 50, u=(15.0, 37.0))
    before = plant.state
    plant.configure(h_op=90.0, T_op=35.0)
    np.testing.assert_array_equal(plant.state, before)
    with pytest.raises(ValueError, match='tau_out: 700 is above max_dead_time'):
        plant.configure(tau_out=700.0)
    with pytest.raises(ValueError, match='h_max: unknown parameter'):
        make_plant('mixing_tank_linear', {'h_max': 150.0})
