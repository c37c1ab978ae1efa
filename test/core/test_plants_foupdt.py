"""The first-order unstable plus dead time plant K/(T·s − 1)·e^(−L·s) ([Precup2013] §3.6.2) against
closed forms and an independent quadrature."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from support.plant_runs import run

from tank_control.core.interfaces import Plant
from tank_control.core.plants.foupdt import Foupdt, FoupdtConfig
from tank_control.core.plants.kinds.registry import make_plant
from tank_control.core.plants.siso import STATE_LIMIT


def test_it_is_a_plant_kind_with_the_documented_defaults():
    plant = make_plant('foupdt')
    assert isinstance(plant, Plant)
    assert (plant.config.gain, plant.config.time_constant, plant.config.dead_time) == \
        (1.0, 10.0, 3.0)


def test_step_response_is_exact_with_a_fractional_dead_time():
    """y = y0 + K·w·(e^((t − L)/T) − 1) after the dead time: the pole at +1/T."""
    K, T, L, y0, step = 0.5, 8.0, 3.3, -2.0, 4.0
    trace = run(Foupdt(FoupdtConfig(gain=K, time_constant=T, dead_time=L, output_offset=y0)),
                lambda t: step, [0.4] * 100)
    t = trace[:, 0]
    expected = y0 + K * step * np.where(t > L, np.expm1((t - L) / T), 0.0)
    np.testing.assert_allclose(trace[:, 1], expected, rtol=1e-13, atol=1e-12)


def test_result_does_not_depend_on_the_step_size_and_matches_quadrature():
    def w(t: float) -> float:
        return 1.0 if t < 6.0 else -0.5 - 0.25 * math.floor(t - 6.0)
    K, T, L = 2.0, 5.0, 1.25
    config = FoupdtConfig(gain=K, time_constant=T, dead_time=L)
    coarse = run(Foupdt(config), w, [1.0] * 12)
    fine = run(Foupdt(config), w, [0.0625] * 192)
    np.testing.assert_allclose(fine[::16], coarse, rtol=1e-13, atol=1e-12)
    # y(t) = ∫ (K/T)·e^((t − s)/T)·w(s − L) ds over (L, t)
    t_end = 12.0
    edges = [L] + [6.0 + k + L for k in range(7) if 6.0 + k + L < t_end] + [t_end]
    independent = sum(quad(lambda s: K / T * math.exp((t_end - s) / T) * w(s - L), a, b,
                           epsabs=1e-12, epsrel=1e-12)[0] for a, b in zip(edges, edges[1:]))
    assert coarse[-1, 1] == pytest.approx(independent, rel=1e-10)


def test_an_equilibrium_is_kept_and_a_small_push_grows_like_the_pole():
    """At rest with u = 0 it stays (x = −K·w = 0); an input pulse grows as e^(t/T)."""
    plant = Foupdt(FoupdtConfig(gain=1.0, time_constant=2.0, dead_time=0.0))
    trace = run(plant, lambda t: 1e-6 if t < 0.1 else 0.0, [0.1] * 101)
    y = trace[:, 1]
    assert y[0] == 0.0
    assert y[-1] / y[1] == pytest.approx(math.exp(10.0 / 2.0), rel=1e-9)


def test_left_open_loop_it_saturates_at_the_state_limit_and_counts_it():
    plant = Foupdt(FoupdtConfig(gain=1.0, time_constant=0.01, dead_time=0.0))
    run(plant, lambda t: 1.0, [1.0] * 5)
    assert abs(plant.outputs()[0]) == STATE_LIMIT
    assert plant.status['clipped_states'] > 0


def test_a_non_positive_time_constant_is_refused_with_a_reason():
    with pytest.raises(ValueError, match='time_constant: 0 is below the minimum'):
        make_plant('foupdt', {'time_constant': 0.0})


def test_it_equals_the_transfer_function_kind_on_the_same_model():
    """K/(T·s − 1)·e^(−L·s) as ``num [K]``, ``den [T, −1]``: the same samples, with a load."""
    def u_of_t(t: float) -> float:
        return math.sin(0.7 * t)
    values = {'gain': 0.8, 'time_constant': 6.0, 'dead_time': 2.35}
    ours = run(make_plant('foupdt', values), u_of_t, [0.1] * 200, v_of_t=lambda t: 0.3)
    other = run(make_plant('transfer_function', {'num': [0.8], 'den': [6.0, -1.0],
                                                 'dead_time': 2.35}),
                u_of_t, [0.1] * 200, v_of_t=lambda t: 0.3)
    np.testing.assert_allclose(ours, other, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize('dt', [1.0, 3600.0])
def test_the_smallest_time_constant_with_a_long_step_saturates_instead_of_overflowing(dt):
    """Found by test_parameter_fuzz: T = 1e-6 s (the smallest allowed) over a
    1 s step made e^(τ/T) = e^(1e6), an OverflowError that ended the plant. The state runs off
    to the limit the plant clips it at (counted); at rest it stays at rest."""
    plant = Foupdt(FoupdtConfig(time_constant=1e-6, dead_time=0.0))
    plant.step(np.array([0.0]), np.array([0.0]), dt)
    assert plant.outputs()[0] == 0.0
    plant.step(np.array([1.0]), np.array([0.0]), dt)
    assert plant.outputs()[0] == STATE_LIMIT           # x runs away from −K·w = −1, upwards
    assert plant.status['clipped_states'] == 1
