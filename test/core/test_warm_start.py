"""Warm start: every controller kind takes over with ``initial_output`` at its first sample
(``core.loop.warm_start`` = ``reset(y, initial_output)``, called by core/loop.py and
controller_node alike), so a plant at its operating point with the setpoints there stays."""
from __future__ import annotations

import numpy as np
import pytest

from tank_control.core import node_specs
from tank_control.core.control.kinds.registry import KINDS
from tank_control.core.loop import run_loop, warm_start
from tank_control.core.params import ConfigError
from tank_control.core.reference import reference_from_params
from tank_control.core.scenario import controller_setup, run_in_process


def make_controller(values: dict):
    """The controller controller_node builds from these parameter values."""
    return controller_setup(values).build_controller()

T0 = 2115.0 / 63.0          # [Michalski2021] operating-point temperature [°C]
H0 = 81.0                   # [cm]
DECOUPLED = {'two_loop.kp_h': 0.04, 'two_loop.ki_h': 0.0004, 'two_loop.kp_T': 0.0,
             'two_loop.ki_T': -0.01}                                        # [Michalski2021] §3.1
SMITH = {'smith.gain': 0.05, 'smith.time_constant': 10.0, 'smith.dead_time': 3.0}


def operating_point_flows() -> tuple[float, float]:
    """[Michalski2021] §1 steady state, solved here: F_H + F_C + F_D = α·√h and
    F_H·T_H + F_C·T_C + F_D·T_D = α·√h·T (α 7, F_D 12 at 33 °C, T_H 62, T_C 23 °C)."""
    total = 7.0 * np.sqrt(H0)
    a = np.array([[1.0, 1.0], [62.0, 23.0]])
    b = np.array([total - 12.0, total * T0 - 12.0 * 33.0])
    f_h, f_c = np.linalg.solve(a, b)
    return float(f_h), float(f_c)


def test_defaults_documented_per_kind():
    defaults = {name: next(s for s in node_specs.controller_specs(name)
                           if s.name == 'initial_output') for name in KINDS}
    for spec in defaults.values():
        assert spec.read_only and 'initial_output' in spec.name and spec.description
    flows = operating_point_flows()
    for name in ('two_loop_pi', 'mpcs'):
        assert defaults[name].default == pytest.approx(list(flows), abs=1e-9)   # 14, 37 cm³/s
    for name in ('pid', 'smith_pi', 'relay_autotune'):
        assert defaults[name].default == [0.0]


def first_output(values: dict, y: np.ndarray, r: np.ndarray, d=()) -> np.ndarray:
    controller = make_controller(values)
    assert warm_start(controller, y)
    return controller.step(0.0, y, r, np.asarray(d, dtype=float))


@pytest.mark.parametrize('values', [
    {'controller': 'pid', 'kp': 2.0, 'ti': 5.0, 'td': 1.0, 'b': 0.4, 'c': 0.6},
    {'controller': 'pid', 'kp': 2.0, 'du_max': 0.01},             # P only, rate limited
    {'controller': 'smith_pi', 'kp': 3.0, 'ti': 10.0, 'smith.model': 'fopdt', **SMITH},
    {'controller': 'smith_pi', 'kp': 3.0, 'ti': 10.0, 'smith.model': 'ipdt', **SMITH},
    {'controller': 'relay_autotune', 'kp': 2.0, 'ti': 5.0},
], ids=['pid', 'p_rate_limited', 'smith_fopdt', 'smith_ipdt', 'relay_autotune'])
def test_siso_first_output_is_initial_output_without_a_bump(values):
    y = np.array([0.8])
    u = first_output({**values, 'sample_time': 0.5, 'initial_output': [1.7]}, y, y)
    assert u == pytest.approx([1.7], abs=1e-12)
    # default: 0, the holding input of an IPDT/FOPDT at rest
    assert first_output({**values, 'sample_time': 0.5}, y, y) == pytest.approx([0.0], abs=1e-12)


@pytest.mark.parametrize('extra', [{}, {'two_loop.decoupling': 'static', **DECOUPLED},
                                   {'two_loop.decoupling': 'dynamic', **DECOUPLED}],
                         ids=['none', 'static', 'dynamic'])
def test_two_loop_pi_first_output_is_the_operating_point(extra):
    y = np.array([H0, T0])
    u = first_output({'controller': 'two_loop_pi', **extra}, y, y)
    assert u == pytest.approx(operating_point_flows(), abs=1e-9)


def test_mpcs_first_output_is_the_operating_point():
    y = np.array([H0, T0])
    u = first_output({'controller': 'mpcs'}, y, y, d=(12.0, 33.0))
    assert u == pytest.approx(operating_point_flows(), abs=1e-9)


def test_manual_mode_starts_at_manual_output_and_limits_clip():
    y = np.array([0.8])
    values = {'controller': 'pid', 'kp': 2.0, 'ti': 5.0, 'initial_output': [1.7]}
    assert first_output({**values, 'mode': 'manual', 'manual_output': 0.3}, y, y) == [0.3]
    clipped = {**values, 'u_min': 0.0, 'u_max': 1.0}
    assert first_output(clipped, y, y) == pytest.approx([1.0], abs=1e-12)


def test_bad_initial_output_rejected_naming_the_parameter():
    with pytest.raises(ConfigError) as info:
        make_controller({'controller': 'two_loop_pi', 'initial_output': [14.0]})
    assert str(info.value).startswith('initial_output') and '2' in str(info.value)
    with pytest.raises(ValueError, match='initial_output'):
        make_controller({'controller': 'pid', 'initial_output': [1.0, 2.0]})


def test_relay_test_requested_at_start_up_survives_the_warm_start():
    values = {'controller': 'relay_autotune', 'kp': 2.0, 'ti': 5.0, 'autotune.start': True,
              'initial_output': [0.5]}
    tuner = make_controller(values)
    assert tuner.state == 'settling'
    warm_start(tuner, np.array([1.0]))
    u = tuner.step(0.0, np.array([1.0]), np.array([1.0]), np.array([]))
    assert tuner.state == 'settling' and u == pytest.approx([0.5], abs=1e-12)


class Recorder:
    """A controller that records the loop's calls."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    sample_time = 1.0
    initial_output = np.array([2.0])
    status: dict = {}

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def reset(self, y, u) -> None:
        self.calls.append(('reset', float(y[0]), float(u[0])))

    def step(self, t, y, r, d):
        self.calls.append(('step', t))
        return np.array([0.0])


class Constant:
    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    status: dict = {}

    def reset(self) -> None: ...
    def outputs(self): return np.array([0.25])
    def step(self, u, d, dt) -> None: ...


def test_loop_resets_once_before_the_first_step_with_the_first_measurement():
    ctrl = Recorder()
    reference = reference_from_params({'setpoint.channels': ['y'], 'setpoint.y.value': 1.0})
    run_loop(Constant(), ctrl, reference, sample_time=1.0, duration=3.0)
    assert ctrl.calls == [('reset', 0.25, 2.0), ('step', 0.0), ('step', 1.0), ('step', 2.0),
                          ('step', 3.0)]


@pytest.mark.parametrize('controller', [
    {'controller': 'two_loop_pi'},
    {'controller': 'two_loop_pi', 'two_loop.decoupling': 'static', **DECOUPLED},
    {'controller': 'two_loop_pi', 'two_loop.decoupling': 'dynamic', **DECOUPLED},
    {'controller': 'mpcs'},
], ids=['two_loop', 'static_decoupler', 'dynamic_decoupler', 'mpcs'])
def test_nonlinear_tank_at_its_operating_point_stays_there(controller):
    """dh/dt = dT/dt = 0 from t = 0: h, T_out and the flows do not move over 600 s (longer
    than the 180 s + 120 s dead times), where a cold start dropped the flows to ~0."""
    mpcs = controller['controller'] == 'mpcs'
    params = {
        'plant': {'plant': 'mixing_tank', 'sample_time': 1.0, 'integration_step': 0.5,
                  'noise_std': [0.0]},
        'controller': {'sample_time': 1.0, **controller},
        'reference': {'setpoint.channels': ['h', 'T_out'], 'setpoint.h.value': H0,
                      'setpoint.T_out.value': T0,
                      'disturbance.channels': ['F_D', 'T_D'] if mpcs else [],
                      **({'disturbance.F_D.value': 12.0, 'disturbance.T_D.value': 33.0}
                         if mpcs else {})},
    }
    trace = run_in_process(params, duration=600.0)
    f_h, f_c = operating_point_flows()
    assert np.max(np.abs(trace['y.h'] - H0)) < 1e-9
    assert np.max(np.abs(trace['y.T_out'] - T0)) < 1e-9
    assert np.max(np.abs(trace['u.F_H'] - f_h)) < 1e-9
    assert np.max(np.abs(trace['u.F_Cin'] - f_c)) < 1e-9
