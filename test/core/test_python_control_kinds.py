"""A controller kind's linear description as python-control objects
(``python_control.controller_transfer_function``/``controller_state_space``): the discrete
transfer function (dt = the controller's sample time) equals the kind's own frequency response,
and python-control's ``stability_margins`` on it times the exact ZOH plant equal the project's
loop analysis."""
from __future__ import annotations

import control
import numpy as np
import pytest

from tank_control import python_control as pc
from tank_control.core import params_file
from tank_control.core.analysis import frequency as fr
from tank_control.core.scenario_loops import loop_cases

# one shipped scenario per kind with a linear description (pid, relay_autotune, lead_lag,
# smith_pi, fsa on a stable and an unstable plant); the Smith predictor's equivalent controller
# has degree ~40 (its model's delay as poles at z = 0), evaluated to ~1e-6
SCENARIOS = [('config/ipdt_pid.yaml', 1e-9), ('config/fopdt_zn.yaml', 1e-9),
             ('config/fopdt_autotune.yaml', 1e-9), ('config/scenarios/tf_002_pid.yaml', 1e-9),
             ('config/scenarios/fopdt_smith_autotune.yaml', 1e-5),
             ('config/scenarios/fopdt_fsa.yaml', 1e-9), ('config/scenarios/foupdt_fsa.yaml', 1e-9)]


def _case(path):
    return loop_cases(params_file.read(path))[0]


@pytest.mark.parametrize('path, rtol', SCENARIOS)
def test_the_kinds_transfer_function_is_its_frequency_response(path, rtol):
    case = _case(path)
    description = case.controller
    h = description.sample_time
    w = np.array([1e-3, 1e-2, 0.1, 0.5, 0.9]) * np.pi / h          # up to 0.9 × Nyquist
    z = np.exp(1j * w * h)
    tf = pc.controller_transfer_function(description)
    assert isinstance(tf, control.TransferFunction) and tf.dt == h
    np.testing.assert_allclose(tf(z), description.feedback(w), rtol=rtol)
    ss = pc.controller_state_space(description)
    assert isinstance(ss, control.StateSpace) and ss.dt == h
    np.testing.assert_allclose(np.ravel(ss(z)), description.feedback(w), rtol=rtol)
    setpoint = description.setpoint if description.setpoint is not None else description.feedback
    np.testing.assert_allclose(pc.controller_transfer_function(description, 'setpoint')(z),
                               setpoint(w), rtol=rtol)


def test_from_a_controllers_parameter_values():
    """The same from the values a scenario's controller section holds."""
    values = {'controller': 'pid', 'kp': 2.0, 'ti': 10.0, 'td': 1.0, 'n': 10.0,
              'sample_time': 0.1}
    tf = pc.controller_transfer_function(values)
    w = np.array([0.01, 0.3, 3.0, 30.0])
    np.testing.assert_allclose(tf(np.exp(1j * w * 0.1)),
                               fr.pid_feedback_discrete(2.0, 10.0, 1.0, 10.0, 0.1)(w),
                               rtol=1e-12)


@pytest.mark.parametrize('path', ['config/ipdt_pid.yaml', 'config/scenarios/tf_002_pid.yaml',
                                  'config/scenarios/fopdt_fsa.yaml'])
def test_python_controls_margins_equal_the_loop_analysis(path):
    """``control.stability_margins`` of C(z)·G(z) (the exact ZOH plant with its dead time, also
    converted exactly) against the project's report of the same loop."""
    case = _case(path)
    h = case.controller.sample_time
    loop = (pc.controller_transfer_function(case.controller)
            * pc.discrete_transfer_function(case.model.response(h)))
    gm, pm, _, wg, wp, _ = control.stability_margins(loop, returnall=False)
    ours = case.report()
    assert ours.stable
    assert ours.phase_margin == pytest.approx(pm, abs=0.05)
    assert ours.wc == pytest.approx(wp, rel=1e-3)
    if np.isfinite(ours.gain_margin):
        assert ours.gain_margin == pytest.approx(gm, rel=1e-3)
        assert ours.w180 == pytest.approx(wg, rel=1e-3)


def test_a_kind_without_a_linear_description_says_why():
    with pytest.raises(ValueError, match='controller mpcs: no linear description: .*nonlinear'):
        pc.controller_transfer_function({'controller': 'mpcs'})
    with pytest.raises(ValueError, match='continuous'):
        pc.discrete_transfer_function(fr.pid_feedback(1.0, 10.0))
    with pytest.raises(ValueError, match='path'):
        pc.controller_transfer_function(_case('config/ipdt_pid.yaml').controller, 'load')


@pytest.mark.parametrize('path', ['config/ipdt_pid.yaml', 'config/fopdt_zn.yaml',
                                  'config/scenarios/tf_002_pid.yaml',
                                  'config/scenarios/fopdt_fsa.yaml'])
def test_the_predicted_step_equals_python_controls_step_response(path):
    """analysis.png's predicted setpoint step (``harness.analysis.predicted_step``, an inverse
    FFT of Y/R) against ``control.step_response`` of ``G·C_r/(1 + G·C)`` built from the
    converted state spaces — over the whole predicted record, the lead-lag loop's slow
    integral tail included (a record cut too short wrapped it around: 1.9 % off). The state
    spaces, not the transfer functions: the product of the loop's polynomials is not minimal
    (its poles at z = 1 cancel), and python-control's simulation of it drifts by 1e-4."""
    from tank_control.harness.analysis import predicted_step
    case = _case(path)
    h = case.controller.sample_time
    c = pc.controller_state_space(case.controller)
    c_r = pc.controller_state_space(case.controller, 'setpoint')
    g = control.tf2ss(pc.discrete_transfer_function(case.model.response(h)))
    t, y = predicted_step(case)
    theirs = control.step_response(control.feedback(g, c) * c_r, T=t)
    assert np.max(np.abs(np.ravel(theirs.outputs) - y)) < 1e-6
    assert y[-1] == pytest.approx(1.0, abs=1e-6)
