"""[Precup2013] §3.7 on [Michalski2021]'s tank, as shipped: config/scenarios/tank_pi_autotuned.yaml (the sequential
relay test tunes the decoupled two-loop PI at the operating point, then [Michalski2021]'s setpoint steps)
and tank_fill_pi_autotuned.yaml (filling with those gains). The claims run in-process; the
lockstep run over ROS equals the in-process one to 1e-9 (cut to the first relay, and the
model_ls design) — docs/scenarios.md, docs/tuning.md."""
from __future__ import annotations

import numpy as np
import pytest
from support import SCENARIOS

from tank_control.core import params_file
from tank_control.core.trace import Trace
from tank_control.harness.runner import run

T0 = 2115.0 / 63.0
GAINS = ('two_loop.kp_h', 'two_loop.ki_h', 'two_loop.kp_T', 'two_loop.ki_T')


def assert_equal_traces(ros_csv, in_process_csv) -> None:
    ros, ref = Trace.read_csv(ros_csv), Trace.read_csv(in_process_csv)
    assert list(ros.columns) == list(ref.columns) and len(ros) == len(ref)
    for name in ref.columns:
        np.testing.assert_allclose(ros.columns[name], ref.columns[name], rtol=0, atol=1e-9,
                                   err_msg=name)


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp('mimo')
    results = {name: run(SCENARIOS / f'{name}.yaml', out / name, in_process=True, plots=False)
               for name in ('tank_pi_autotuned', 'tank_pi', 'tank_fill_pi_autotuned',
                            'tank_fill_pi_decoupled')}
    results['model_ls'] = run(SCENARIOS / 'tank_pi_autotuned.yaml', out / 'model_ls',
                              overrides=('controller.autotune.mode=model_ls',),
                              in_process=True, plots=False)
    return results


def steps(result, channel):
    return result.metrics['outputs'][channel]['steps']


@pytest.mark.slow
def test_sequential_relay_tunes_then_level_steps_meet_the_goal(runs):
    """The test ends (state running) before the first step at 12100 s; level overshoot ≤ 10 %
    on both level steps; T_out's peak deviation on each level step below that of [Michalski2021]'s PI
    without decoupling (tank_pi, the same steps)."""
    tuned, plain = runs['tank_pi_autotuned'], runs['tank_pi']
    at = tuned.metrics['controller']['autotune']
    assert at['autotune.state'] == 'running' and at['autotune.reason'] == ''
    assert at['autotune.state_time'] < 12100.0 - 2000.0        # settled 2000 s before a step
    gains = tuned.metrics['controller']['final_gains']
    assert [gains[k] for k in GAINS] == [at['autotune.proposed_kp_h'],
                                         at['autotune.proposed_ki_h'],
                                         at['autotune.proposed_kp_T'],
                                         at['autotune.proposed_ki_T']]
    assert gains['two_loop.kp_h'] != 0.04                        # not the file's gains
    level, level_plain = steps(tuned, 'h'), steps(plain, 'h')
    assert [s['r_to'] for s in level] == [s['r_to'] for s in level_plain] == [90.0, 75.0]
    for mine, theirs in zip(level, level_plain):
        assert mine['overshoot_pct'] <= 10.0
        dev = mine['interaction']['T_out']['peak_error']
        assert dev < theirs['interaction']['T_out']['peak_error']
    # every setpoint is reached: within 5 % of each change 4000 s after it at the latest
    y = tuned.trace.columns
    for channel, t_end, target in (('h', 16100, 90.0), ('T_out', 18100, 36.0)):
        k = int(np.searchsorted(tuned.trace.t, t_end)) - 1
        assert abs(y[f'y.{channel}'][k] - target) < 0.05 * abs(target - (81.0 if channel == 'h'
                                                                       else T0))


@pytest.mark.slow
def test_least_squares_design_on_the_model_meets_the_level_goal_too(runs):
    """model_ls ([Precup2013] eqs. 3.7.8–3.7.10, default target) designed at 1 s on the linearised tank:
    level overshoot ≤ 10 % and less T_out deviation on level steps than tank_pi."""
    ls, plain = runs['model_ls'], runs['tank_pi']
    at = ls.metrics['controller']['autotune']
    assert at['autotune.state'] == 'running' and 0.0 < at['autotune.ls_residual'] < 0.5
    for mine, theirs in zip(steps(ls, 'h'), steps(plain, 'h')):
        assert mine['overshoot_pct'] <= 10.0
        assert (mine['interaction']['T_out']['peak_error']
                < theirs['interaction']['T_out']['peak_error'])


@pytest.mark.slow
def test_filling_with_the_tuned_gains(runs):
    """tank_fill_pi_autotuned (and tank_mpcs_two_loop_autotuned, the auto-tuned row of the tank
    comparison) hold the gains the relay test found (to 1e-9); tank_fill_pi_autotuned
    fills the tank without level overshoot beyond 10 %, with a smaller T_out peak than [Michalski2021]'s
    decoupled gains (tank_fill_pi_decoupled)."""
    tuned = runs['tank_pi_autotuned'].metrics['controller']['final_gains']
    for name in ('tank_fill_pi_autotuned', 'tank_mpcs_two_loop_autotuned'):  # and the compare row
        file_gains = params_file.read(SCENARIOS / f'{name}.yaml')['controller']
        assert [file_gains[k] for k in GAINS] == pytest.approx([tuned[k] for k in GAINS],
                                                               rel=1e-9), name
    fill, doc = runs['tank_fill_pi_autotuned'], runs['tank_fill_pi_decoupled']
    (h_step,) = steps(fill, 'h')
    assert h_step['overshoot_pct'] <= 10.0
    assert steps(fill, 'T_out')[0]['peak'] < steps(doc, 'T_out')[0]['peak']
    y = fill.trace.columns
    assert abs(y['y.h'][-1] - 81.0) < 0.5 and abs(y['y.T_out'][-1] - T0) < 0.05


@pytest.mark.parametrize('duration, overrides', [
    (1500.0, ()),                                                     # settling, relay on loop h
    (600.0, ('controller.autotune.mode=model_ls',)),                  # designed at t = 1 s
])
def test_lockstep_over_ros_equals_in_process(tmp_path, ros_env, duration, overrides):
    scenario = SCENARIOS / 'tank_pi_autotuned.yaml'
    ros = run(scenario, tmp_path / 'ros', duration=duration, overrides=overrides, env=ros_env,
              plots=False)
    ref = run(scenario, tmp_path / 'ref', duration=duration, overrides=overrides,
              in_process=True, plots=False)
    assert_equal_traces(ros.files['trace'], ref.files['trace'])
    assert ros.metrics['run']['missed_samples'] == 0
    a, b = (r.metrics['controller'] for r in (ros, ref))
    for key in ('autotune.state', 'autotune.relay_stage', 'autotune.relay_loop',
                'autotune.cycles'):
        assert a['autotune'][key] == b['autotune'][key], key
    for key in GAINS:
        assert a['final_gains'][key] == pytest.approx(b['final_gains'][key], rel=1e-9), key
    if overrides:
        assert a['autotune']['autotune.state'] == 'running'
        assert a['final_gains']['two_loop.kp_h'] == a['autotune']['autotune.proposed_kp_h']
    else:
        assert a['autotune']['autotune.state'] in ('relay', 'measuring')
        assert a['autotune']['autotune.relay_loop'] == 'h'
