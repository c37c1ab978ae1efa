"""Controller kind ``lead_lag`` (core/control/kinds/lead_lag.py) through the paths every kind
takes: parameters, [Ikonen]'s design written back and enforced, live changes, mode, faults, warm
start and an in-process run of a parameter file's sections."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core import node_specs
from tank_control.core.analysis import frequency as fr
from tank_control.core.control.kinds import registry
from tank_control.core.loop import warm_start
from tank_control.core.params import ConfigError
from tank_control.core.scenario import controller_setup, run_in_process

DESIGN_002 = {'controller': 'lead_lag', 'tuning.rule': 'frequency_002', 'tuning.model': 'sopdt',
              'tuning.gain': 2.0, 'tuning.time_constant': 1.0, 'tuning.time_constant2': 0.5,
              'sample_time': 0.01}


def make(values: dict):
    return controller_setup(values).build_controller()


def change(ctrl, values: dict, changed: set, t: float, y: float, r: float):
    """A live change as controller_node applies it at the sample at time t."""
    setup = controller_setup(values, given=())
    new, u = registry.step_with_changes(setup.kind, ctrl, setup.settings, frozenset(changed), t,
                                        np.array([y]), np.array([r]), np.array([]))
    return new, float(u[0])


def step(ctrl, t: float, y: float, r: float) -> float:
    return float(ctrl.step(t, np.array([y]), np.array([r]), np.array([]))[0])


def matched_lead_gain(td: float, alpha: float, h: float) -> float:
    """gd = g − 1 of the matched pole-zero lead g·(z − z0)/(z − p0) = 1 + gd·(z − 1)/(z − p0)."""
    z0, p0 = math.exp(-h / td), math.exp(-h / (alpha * td))
    return (1 - p0) / (1 - z0) - 1


def test_registered_with_its_parameters_described():
    specs = {s.name: s for s in node_specs.controller_specs('lead_lag')}
    for name in ('lead_lag.kp', 'lead_lag.td', 'lead_lag.alpha', 'lead_lag.ti', 'sample_time',
                 'u_min', 'u_max', 'anti_windup', 'tracking_time', 'direct_action', 'mode',
                 'manual_output', 'fail_safe', 'initial_output', 'tuning.rule', 'tuning.kind',
                 'tuning.model', 'tuning.gain', 'tuning.time_constant', 'tuning.time_constant2',
                 'tuning.dead_time', 'tuning.phase_margin', 'tuning.steady_state_error',
                 'tuning.integral_ratio', 'output_names', 'input_names'):
        assert name in specs, name
    assert 0.0 < specs['lead_lag.alpha'].min < specs['lead_lag.alpha'].max < 1.0   # a lead
    assert '[Ikonen]' in specs['lead_lag.td'].description and '[s]' in specs['lead_lag.td'].description
    assert specs['tuning.rule'].choices == ('none', 'frequency_002')
    assert specs['sample_time'].read_only and specs['lead_lag.ti'].default == 0.0   # none


def test_hand_set_compensator_is_the_configured_law():
    """kp, td, alpha, ti by hand: after a setpoint step from rest the first output is
    kp·(1 + gd)·Δr (the lead's matched gain at z = ∞); the integral acts from the next."""
    values = {'controller': 'lead_lag', 'lead_lag.kp': 2.0, 'lead_lag.td': 1.5,
              'lead_lag.alpha': 0.2, 'lead_lag.ti': 8.0, 'sample_time': 0.5,
              'output_names': ['h'], 'input_names': ['F_H']}
    ctrl = make(values)
    assert ctrl.output_names == ('h',) and ctrl.input_names == ('F_H',)
    assert ctrl.sample_time == 0.5
    assert step(ctrl, 0.0, 0.0, 0.0) == 0.0
    gd = matched_lead_gain(1.5, 0.2, 0.5)
    assert step(ctrl, 0.5, 0.0, 1.0) == pytest.approx(2.0 * (1 + gd), rel=1e-12)


def test_002_design_is_derived_written_back_and_enforced():
    """tuning.rule frequency_002 sets lead_lag.kp, lead_lag.td, lead_lag.ti ([Ikonen] §1.1–1.4):
    pd → kp 9.5 (5 % steady-state error, [Ikonen] §1.1) and no integral; a hand value for a
    derived parameter is refused naming the rule, its own value is accepted."""
    pd = controller_setup({**DESIGN_002, 'tuning.kind': 'pd'}).settings.values
    assert pd['lead_lag.kp'] == pytest.approx(9.5, rel=1e-12) and pd['lead_lag.ti'] == 0.0
    m = fr.margins(fr.lead(pd['lead_lag.kp'], pd['lead_lag.td'], 1 / 0.1)
                   * fr.rational([4.0], [1.0, 3.0, 2.0]))
    assert round(m.phase_margin, 1) == 70.5 and round(m.wc, 1) == 10.9     # [Ikonen] Fig. 6
    pid = controller_setup({**DESIGN_002, 'tuning.kind': 'pid'}).settings.values
    assert pid['lead_lag.td'] == pd['lead_lag.td'] and pid['lead_lag.ti'] > 0.0
    with pytest.raises(ConfigError) as info:
        make({**DESIGN_002, 'lead_lag.kp': 2.0})
    text = str(info.value)
    assert text.startswith('lead_lag.kp: 2 conflicts with tuning.rule') and 'none' in text
    assert make({**DESIGN_002, **{k: pid[k] for k in ('lead_lag.kp', 'lead_lag.td',
                                                      'lead_lag.ti')}}) is not None
    # alpha is the design's input: a smaller alpha gives more lead, a different td
    other = controller_setup({**DESIGN_002, 'tuning.kind': 'pd', 'lead_lag.alpha': 0.05})
    assert other.settings.values['lead_lag.td'] != pd['lead_lag.td']


@pytest.mark.parametrize('values, name', [
    ({'tuning.kind': 'pd', 'tuning.model': 'ipdt', 'tuning.time_constant': 0.0,
      'tuning.time_constant2': 0.0}, 'tuning.kind'),
    ({'tuning.gain': 0.0}, 'tuning.gain'),
    ({'tuning.model': 'fopdt'}, 'tuning.time_constant2'),
    ({'lead_lag.alpha': 1.0}, 'lead_lag.alpha'),
    ({'lead_lag.kp': 0.0, 'tuning.rule': 'none'}, 'lead_lag.kp'),
    ({'u_min': 1.0, 'u_max': 1.0}, 'u_min'),
    ({'manual_output': 5.0, 'u_max': 1.0}, 'manual_output'),
    ({'lead_lag.tdd': 1.0}, 'lead_lag.tdd'),
])
def test_bad_values_refused_with_one_line_naming_the_parameter(values, name):
    with pytest.raises(ConfigError) as info:
        make({**DESIGN_002, **values})
    assert str(info.value).startswith(name + ':'), str(info.value)
    assert '\n' not in str(info.value)


def test_live_change_is_bumpless_in_place_and_then_in_effect():
    """A gain, lead and integral change at a sample with a steady error: the output of that
    sample is the old law's (no bump), the object is kept; the next error step moves the
    output by the new law: kp'·(1 + gd')·Δe plus the integral increment kp'·h/ti'·e."""
    values = {'controller': 'lead_lag', 'lead_lag.kp': 1.0, 'lead_lag.td': 2.0,
              'lead_lag.alpha': 0.2, 'lead_lag.ti': 10.0, 'sample_time': 1.0}
    ctrl, twin = make(values), make(values)
    for k in range(40):                       # constant error 0.5: the lead comes to rest
        u = step(ctrl, float(k), 0.5, 1.0)
        assert step(twin, float(k), 0.5, 1.0) == u
    values.update({'lead_lag.kp': 3.0, 'lead_lag.td': 4.0, 'lead_lag.ti': 5.0})
    new, u_change = change(ctrl, values, {'lead_lag.kp', 'lead_lag.td', 'lead_lag.ti'}, 40.0,
                           0.5, 1.0)
    assert new is ctrl
    assert u_change == pytest.approx(step(twin, 40.0, 0.5, 1.0), abs=1e-12)
    gd = matched_lead_gain(4.0, 0.2, 1.0)
    u_next = step(ctrl, 41.0, 0.4, 1.0)                    # error 0.5 → 0.6
    assert u_next - u_change == pytest.approx(3.0 * (1 + gd) * 0.1 + 3.0 * 1.0 / 5.0 * 0.5,
                                              rel=1e-9)
    assert (ctrl.lead_lag.config.kp, ctrl.lead_lag.config.td) == (3.0, 4.0)


def test_non_finite_measurement_holds_the_last_output():
    values = {'controller': 'lead_lag', 'lead_lag.kp': 2.0, 'lead_lag.ti': 4.0,
              'lead_lag.td': 1.0, 'u_max': 100.0}
    ctrl = make(values)
    for k in range(5):
        u = step(ctrl, float(k), 0.2 * k, 1.0)
    for bad in (math.nan, math.inf):
        assert step(ctrl, 5.0, bad, 1.0) == u
        assert ctrl.status['input_fault'] is True
    assert step(ctrl, 6.0, 0.8, 1.0) == pytest.approx(u, abs=1e-12)   # resumes from the held u
    assert ctrl.status['input_fault'] is False


def test_warm_start_takes_over_with_initial_output():
    values = {'controller': 'lead_lag', 'lead_lag.kp': 2.0, 'lead_lag.td': 1.0,
              'lead_lag.ti': 5.0, 'initial_output': [1.7], 'sample_time': 0.5}
    ctrl = make(values)
    y = np.array([0.8])
    assert warm_start(ctrl, y)
    assert [float(ctrl.step(0.5 * k, y, y, np.array([]))[0]) for k in range(3)] == \
        pytest.approx([1.7] * 3, abs=1e-12)
    ctrl = make({**values, 'u_max': 1.0})                 # clipped to the limits
    assert warm_start(ctrl, y) and float(ctrl.step(0.0, y, y, np.array([]))[0]) == 1.0


def test_limits_and_direct_action():
    values = {'controller': 'lead_lag', 'lead_lag.kp': 2.0, 'lead_lag.td': 1.0,
              'u_min': -1.0, 'u_max': 3.0}
    ctrl = make(values)
    step(ctrl, 0.0, 0.0, 0.0)
    assert step(ctrl, 1.0, 0.0, 10.0) == 3.0 and ctrl.status['saturated'] is True
    reverse = make({**values, 'direct_action': True})
    step(reverse, 0.0, 0.0, 0.0)
    assert step(reverse, 1.0, 0.0, 0.2) < 0.0                    # setpoint up → output down
    assert step(reverse, 2.0, 0.0, 10.0) == -1.0


def test_in_process_run_of_a_parameter_file_on_the_fopdt_plant():
    """A parameter file's sections (plant fopdt K 1, T 10 s, L 1 s; lead_lag with the [Ikonen] PID
    design on that model; a setpoint step) run through the in-process loop: the output stays
    within its limits, the loop settles at the setpoint without steady-state error, and the
    overshoot is below the 10 % a 60 deg margin allows ([Ikonen]: ζ ≈ PM/100)."""
    sections = {
        '/**': {'clock_mode': 'lockstep'},
        'plant': {'plant': 'fopdt', 'sample_time': 0.05, 'gain': 1.0, 'time_constant': 10.0,
                  'dead_time': 1.0},
        'controller': {'controller': 'lead_lag', 'sample_time': 0.05, 'output_names': ['y'],
                       'input_names': ['u'], 'tuning.rule': 'frequency_002',
                       'tuning.kind': 'pid', 'tuning.model': 'fopdt', 'tuning.gain': 1.0,
                       'tuning.time_constant': 10.0, 'tuning.dead_time': 1.0,
                       'tuning.steady_state_error': 0.1, 'u_min': -20.0, 'u_max': 20.0},
        'reference': {'setpoint.channels': ['y'], 'setpoint.y.times': [0.0, 1.0],
                      'setpoint.y.values': [0.0, 1.0]},
    }
    trace = run_in_process(sections, duration=80.0)
    t, y, u = trace.t, trace['y.y'], trace['u.u']
    assert u.min() >= -20.0 and u.max() <= 20.0
    assert y[t > 70.0] == pytest.approx(1.0, abs=2e-3)
    assert y.max() < 1.10
