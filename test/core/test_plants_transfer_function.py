"""The transfer-function plant with dead time: exact ZOH responses against closed forms and the
other plant kinds, stable, integrating and unstable denominators, and its refusals."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.plants.kinds.registry import make_plant


def run(plant, u, steps, h, v=0.0):
    y = [plant.outputs()[0]]
    for k in range(steps):
        plant.step([u(k * h) if callable(u) else u], [v], h)
        y.append(plant.outputs()[0])
    return np.array(y)


def test_the_document_process_step_response_is_the_closed_form_at_every_sample():
    # 4/((s + 1)(s + 2)) with L = 0.35 s (not a multiple of the tick): partial fractions give
    # y(t) = 2·(1 − 2·e^(−τ) + e^(−2τ)), τ = t − L, for a unit step.
    plant = make_plant('transfer_function', {'dead_time': 0.35})
    h, n = 0.1, 80
    y = run(plant, 1.0, n, h)
    tau = np.maximum(np.arange(n + 1) * h - 0.35, 0.0)
    np.testing.assert_allclose(y, 2 * (1 - 2 * np.exp(-tau) + np.exp(-2 * tau)), atol=1e-12)


def test_the_response_does_not_depend_on_the_step_size():
    coarse = run(make_plant('transfer_function', {'dead_time': 0.35, 'num': [1.0, 3.0]}),
                 lambda t: math.sin(t), 40, 0.1)
    fine = run(make_plant('transfer_function', {'dead_time': 0.35, 'num': [1.0, 3.0]}),
               lambda t: math.sin(math.floor(t * 10 + 1e-9) / 10), 400, 0.01)
    np.testing.assert_allclose(coarse, fine[::10], atol=1e-11)


def test_an_unstable_first_order_process_grows_as_its_closed_form():
    # K/(T·s − 1): a unit step gives K·(e^(t/T) − 1) after the dead time.
    K, T, L = 2.0, 4.0, 1.0
    plant = make_plant('transfer_function', {'num': [K], 'den': [T, -1.0], 'dead_time': L})
    y = run(plant, 1.0, 60, 0.1)
    tau = np.maximum(np.arange(61) * 0.1 - L, 0.0)
    np.testing.assert_allclose(y, K * np.expm1(tau / T), rtol=1e-12, atol=1e-14)
    assert math.isinf(plant.static_gain) is False and plant.static_gain == -K


def test_it_equals_the_sopdt_and_ipdt_kinds_on_their_models():
    # 2/((s + 1)(0.5·s + 1)) = 4/(s² + 3s + 2); input load v and a live dead-time change.
    tf = make_plant('transfer_function', {'num': [4.0], 'den': [1.0, 3.0, 2.0], 'dead_time': 0.3})
    so = make_plant('sopdt', {'gain': 2.0, 'time_constant_1': 1.0, 'time_constant_2': 0.5,
                              'dead_time': 0.3})
    ip = make_plant('ipdt', {'gain': 0.5, 'dead_time': 0.3})
    it = make_plant('transfer_function', {'num': [0.5], 'den': [1.0, 0.0], 'dead_time': 0.3})
    u = lambda t: 1.0 if t < 2 else -0.5        # noqa: E731
    for plants in ((tf, so), (ip, it)):
        a = run(plants[0], u, 30, 0.1, v=0.2)
        b = run(plants[1], u, 30, 0.1, v=0.2)
        for plant in plants:
            plant.configure(dead_time=0.75)
        a = np.concatenate([a, run(plants[0], u, 30, 0.1)])
        b = np.concatenate([b, run(plants[1], u, 30, 0.1)])
        np.testing.assert_allclose(a, b, atol=1e-12)
    assert math.isinf(it.static_gain)


def test_leading_zeros_and_a_scaled_denominator_give_the_same_plant():
    a = run(make_plant('transfer_function', {'num': [0.0, 4.0], 'den': [1.0, 3.0, 2.0]}),
            1.0, 20, 0.1)
    b = run(make_plant('transfer_function', {'num': [8.0], 'den': [0.0, 2.0, 6.0, 4.0]}),
            1.0, 20, 0.1)
    np.testing.assert_allclose(a, b, atol=1e-13)


@pytest.mark.parametrize('values, words', [
    ({'num': [1.0, 2.0, 3.0]}, 'num: degree 2 must be below the degree 2 of den'),
    ({'num': [1.0], 'den': [5.0]}, 'num: degree 0 must be below the degree 0 of den'),
    ({'den': [0.0, 0.0]}, 'den: .* has no non-zero coefficient'),
    ({'den': [1.0] * 12}, 'den: degree 11 is above 10'),
    ({'num': [float('nan')]}, 'num: .*not finite'),
])
def test_bad_polynomials_are_refused_with_a_reason(values, words):
    with pytest.raises(ValueError, match=words):
        make_plant('transfer_function', values)


def test_a_live_change_keeps_the_state_and_refuses_a_new_order():
    plant = make_plant('transfer_function')
    run(plant, 1.0, 10, 0.1)
    before = plant.outputs()[0]
    with pytest.raises(ValueError, match='den: degree 1 differs from the running 2'):
        plant.configure(den=[1.0, 1.0])
    assert plant.config.den == (1.0, 3.0, 2.0) and plant.outputs()[0] == before
    plant.configure(num=[8.0])                  # same state, twice the output map
    assert plant.outputs()[0] == pytest.approx(2 * before, rel=1e-14)
    assert plant.status['order'] == 2
