"""python-control round trips (tank_control/python_control.py), checked against python-control's
own ``stability_margins`` and ``step_response`` on the same systems."""
from __future__ import annotations

import math

import control
import numpy as np
import pytest

from tank_control import python_control as pc
from tank_control.core.analysis import frequency as fr
from tank_control.core.plants.transfer_function import TransferFunction, TransferFunctionConfig
from tank_control.core.tuning.model import ProcessModel

FOPDT = ProcessModel('fopdt', gain=2.0, dead_time=1.0, time_constant=5.0)
SOPDT = ProcessModel('sopdt', gain=1.5, dead_time=2.0, time_constant=4.0, time_constant2=1.0)


@pytest.mark.parametrize('model, gains', [(FOPDT, dict(kp=1.2, ti=5.0)),
                                          (SOPDT, dict(kp=1.0, ti=4.0, td=0.8, n=10.0))])
def test_margins_with_the_exact_delay_equal_python_controls(model, gains):
    """The loop PID·G with the exact dead time: GM, PM and their frequencies from the project
    (``frequency.margins``) and from ``control.stability_margins`` on frequency data."""
    loop = fr.pid_feedback(**gains) * model.response()
    ours = fr.margins(loop)
    w = np.logspace(-3, 2, 20000)
    c = pc.pid_transfer_function(**gains)
    data = pc.to_frequency_data(model, w)
    # the controller's own response: python-control's C times the exact-delay data
    theirs_data = control.frd(c(1j * w) * data.frdata[0, 0], w)
    gm, pm, _, wg, wp, _ = control.stability_margins(theirs_data, returnall=False)
    assert ours.gain_margin == pytest.approx(gm, rel=2e-3)
    assert ours.phase_margin == pytest.approx(pm, abs=0.1)
    assert ours.w180 == pytest.approx(wg, rel=2e-3)
    assert ours.wc == pytest.approx(wp, rel=2e-3)
    # and python-control's PID equals the project's law on the grid
    np.testing.assert_allclose(c(1j * w), fr.pid_feedback(**gains)(w), rtol=1e-9)


def test_pade_transfer_function_step_follows_the_exact_plant():
    """The Padé model's step response (python-control) against the project's exact FOPDT plant:
    equal away from the dead-time edge, where a Padé approximant rings."""
    g = pc.to_transfer_function(FOPDT, pade_order=8)
    t = np.arange(0.0, 30.0, 0.05)
    _, y_pade = control.step_response(g, t)
    plant = FOPDT.plant()
    y = []
    for _ in t:
        y.append(float(plant.outputs()[0]))
        plant.step(np.array([1.0]), np.array([0.0]), 0.05)
    y = np.array(y)
    away = np.abs(t - FOPDT.dead_time) > 0.5
    assert np.max(np.abs(y_pade - y)[away]) < 0.01 * FOPDT.gain


def test_a_control_transfer_function_and_a_delay_run_as_the_plant():
    """``plant_settings``: 002's 4/((s+1)(s+2)) with L = 0.5 s from python-control runs as the
    project's transfer_function plant; its exact step equals python-control's step of the
    delay-free system shifted by L."""
    s = control.tf('s')
    g = 4 / ((s + 1) * (s + 2))
    settings = pc.plant_settings(g, 0.5)
    assert settings == {'plant': 'transfer_function', 'num': [4.0], 'den': [1.0, 3.0, 2.0],
                        'dead_time': 0.5}
    params = {k: v for k, v in settings.items() if k != 'plant'}
    plant = TransferFunction(TransferFunctionConfig(
        num=tuple(params['num']), den=tuple(params['den']), dead_time=params['dead_time']))
    h = 0.1
    t = np.arange(0.0, 8.0, h)
    y = []
    for _ in t:
        y.append(float(plant.outputs()[0]))
        plant.step(np.array([1.0]), np.array([0.0]), h)
    _, y_free = control.step_response(g, t)
    shift = int(round(0.5 / h))
    np.testing.assert_allclose(np.array(y)[shift:], y_free[:len(t) - shift], atol=1e-9)
    assert np.all(np.array(y)[:shift] == 0.0)


def test_what_python_control_gives_that_is_not_a_plant_is_refused_with_a_reason():
    s = control.tf('s')
    with pytest.raises(ValueError, match='strictly proper'):
        pc.plant_settings((s + 1) / (s + 2))
    with pytest.raises(ValueError, match='discrete'):
        pc.plant_settings(control.tf([1.0], [1.0, -0.5], 0.1))
    with pytest.raises(ValueError, match='dead_time'):
        pc.plant_settings(1 / (s + 1), -1.0)
    with pytest.raises(ValueError, match='SISO'):
        pc.plant_settings(control.tf([[[1.0], [1.0]]], [[[1.0, 1.0], [1.0, 2.0]]]))


def test_the_frequency_data_keep_the_exact_delay():
    w = np.array([0.1, 1.0, 3.0])
    data = pc.to_frequency_data(FOPDT, w)
    expected = FOPDT.gain / (1j * w * FOPDT.time_constant + 1) * np.exp(-1j * w * FOPDT.dead_time)
    np.testing.assert_allclose(data.frdata[0, 0], expected, rtol=1e-12)
    tf = pc.to_transfer_function(FOPDT, pade_order=6)
    phase_err = np.angle(tf(1j * w) / expected)
    assert np.max(np.abs(phase_err)) < math.radians(1.0)
