"""Robustness of the implemented loop (core/analysis/robustness.py) and the live guard of the
PID-based kinds (``robustness.ms_max``, ``robustness.*`` results), without ROS.

Independent references: the exact dead-time plant of test/support/relay.py (its own
integration, fractional delay included) driven by the implemented ``Pid2Dof``; the P-loop's
stability limit found by simulation."""
from __future__ import annotations

import math

import numpy as np
import pytest
from support.relay import ExactDelayPlant

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.robustness import RobustnessMonitor, loop_report, predict
from tank_control.core.control.kinds import pid as pid_kind
from tank_control.core.control.kinds import relay_autotune as relay_kind
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.pid import Pid2Dof, PidConfig
from tank_control.core.params import ConfigError
from tank_control.core.tuning.model import ProcessModel

FOPDT_001 = ProcessModel('fopdt', 0.05, 3.0, 10.0)
ZN_001 = dict(kp=70.92, ti=5.5, td=1.32)              # [DeadTimeNotes]'s example, Table 6.2 gains


def simulate(plant: ExactDelayPlant, config: PidConfig, steps: int, r: float, v: float
             ) -> np.ndarray:
    pid = Pid2Dof(config)
    pid.reset(0.0, 0.0, 0.0)
    y = np.empty(steps)
    for k in range(steps):
        y[k] = plant.outputs()[0]
        plant.step(np.array([pid.update(r, y[k])]), np.array([v]), config.sample_time)
    return y


@pytest.mark.parametrize('model, plant', [
    (ProcessModel('fopdt', 0.05, 3.05, 10.0), ExactDelayPlant(0.05, 10.0, 3.05)),
    (ProcessModel('ipdt', 0.05, 5.0), ExactDelayPlant(0.05, None, 5.0)),
])
def test_prediction_is_the_implemented_loop_on_an_exact_plant(model, plant):
    """predict() equals the implemented PID on an independently integrated exact plant
    (fractional dead time included), for the setpoint and the load step."""
    config = PidConfig(kp=20.0 if model.kind == 'fopdt' else 2.0, ti=12.0 if model.kind ==
                       'fopdt' else 30.0, td=1.0, b=0.5, c=0.0, sample_time=0.1)
    p = predict(model, config, duration=80.0)
    plant.reset()
    ys = simulate(plant, config, p.t.size, 1.0, 0.0)
    plant.reset()
    yl = simulate(plant, config, p.t.size, 0.0, 1.0)
    assert np.max(np.abs(p.setpoint - ys)) < 1e-9
    assert np.max(np.abs(p.load - yl)) < 1e-9
    peak = (np.max(ys) - 1.0) * 100
    assert p.overshoot == pytest.approx(max(peak, 0.0), abs=1e-6)
    assert p.iae_load == pytest.approx(np.sum(0.5 * (np.abs(yl[1:]) + np.abs(yl[:-1])) * 0.1))


def test_stability_flag_and_gain_margin_agree_with_simulation():
    """P control: the reported gain margin is the factor to the stability limit of the
    sampled loop: the simulated loop decays at 0.95 of it and grows at 1.05."""
    config = PidConfig(kp=50.0, sample_time=0.1)
    rep = loop_report(FOPDT_001, config)
    limit = 50.0 * rep.gain_margin
    for factor, stable in ((0.95, True), (1.05, False)):
        cfg = PidConfig(kp=factor * limit, sample_time=0.1)
        assert loop_report(FOPDT_001, cfg).stable is stable
        y = simulate(ExactDelayPlant(0.05, 10.0, 3.0), cfg, 3000, 1.0, 0.0)
        error = np.abs(y - np.mean(y[-300:]))
        grows = np.max(error[-300:]) > np.max(error[300:600])
        assert grows is not stable


def test_report_of_001_zn_pid_is_the_frequency_modules():
    rep = loop_report(FOPDT_001, PidConfig(sample_time=0.1, **ZN_001))
    loop = fr.pid_feedback_discrete(sample_time=0.1, **ZN_001) * fr.fopdt_zoh(0.05, 10, 3, 0.1)
    m = fr.margins(loop)
    assert (rep.ms, rep.gain_margin, rep.phase_margin) == pytest.approx((m.ms, m.gain_margin,
                                                                         m.phase_margin))
    assert rep.stable and rep.model == FOPDT_001.describe()


def test_monitor_recomputes_only_when_the_loop_changes():
    monitor = RobustnessMonitor()
    config = PidConfig(sample_time=0.1, **ZN_001)
    first = monitor.report(FOPDT_001, config)
    assert monitor.report(FOPDT_001, config) is first
    assert monitor.report(FOPDT_001, PidConfig(sample_time=0.1, u_max=5.0, **ZN_001)) is first
    changed = monitor.report(FOPDT_001, PidConfig(sample_time=0.1, **{**ZN_001, 'kp': 40.0}))
    assert changed is not first and changed.ms < first.ms
    assert monitor.report(None, config) is None


# ----------------------------------------------------------------------------- the guard
MODEL_001 = {'tuning.gain': 0.05, 'tuning.time_constant': 10.0, 'tuning.dead_time': 3.0,
             'sample_time': 0.1}


def test_guard_refuses_a_gain_change_with_the_numbers():
    """Ms of [DeadTimeNotes]'s ZN PID on the model is 2.73 (frequency module); with ms_max 2 the gains are
    refused naming the gains and both numbers, in a file (all names given) as live."""
    ms = loop_report(FOPDT_001, PidConfig(sample_time=0.1, **ZN_001)).ms
    values = {**MODEL_001, 'robustness.ms_max': 2.0, **ZN_001}
    with pytest.raises(ConfigError) as info:
        resolve(pid_kind.KIND, values)
    text = str(info.value)
    assert text.startswith('kp, ti, td: ') and f'Ms would be {ms:.3g} > robustness.ms_max 2' in text
    with pytest.raises(ConfigError, match='Ms would be'):
        resolve(pid_kind.KIND, values, given={'kp'})
    resolve(pid_kind.KIND, values, given=())            # the node's own re-resolution
    resolve(pid_kind.KIND, {**values, 'kp': 35.0, 'td': 0.0, 'ti': 10.0}, given={'kp'})
    resolve(pid_kind.KIND, {**values, 'robustness.ms_max': 3.0}, given={'kp'})


def test_guard_refuses_an_unstable_loop_and_a_bound_below_the_running_ms():
    values = {**MODEL_001, 'robustness.ms_max': 2.0, 'kp': 200.0, 'ti': 5.0}
    with pytest.raises(ConfigError, match='kp, ti: the loop would be unstable'):
        resolve(pid_kind.KIND, values, given={'kp', 'ti'})
    with pytest.raises(ConfigError, match='robustness.ms_max: Ms would be'):
        resolve(pid_kind.KIND, {**MODEL_001, **ZN_001, 'robustness.ms_max': 1.5},
                given={'robustness.ms_max'})
    with pytest.raises(ConfigError, match='robustness.ms_max: 0.5 is out of range'):
        resolve(pid_kind.KIND, {'robustness.ms_max': 0.5})


def test_guard_checks_a_tuning_rule_but_not_a_model_update():
    """A rule whose gains exceed the bound is refused (named tuning.rule); the ms rule on the
    same model is accepted; a change of the model alone (rule none) is not refused — the
    running loop's Ms is reported in robustness.* with a warning instead."""
    base = {**MODEL_001, 'robustness.ms_max': 2.0, 'tuning.ku': 117.8, 'tuning.tu': 10.82}
    with pytest.raises(ConfigError, match='tuning.rule: Ms would be'):
        resolve(pid_kind.KIND, {**base, 'tuning.rule': 'zn_001'}, given={'tuning.rule'})
    settings = resolve(pid_kind.KIND, {**base, 'tuning.rule': 'ms', 'tuning.kind': 'pid'},
                       given={'tuning.rule', 'tuning.kind'})
    assert settings.values['kp'] > 0 and settings.values['td'] > 0
    hand = {**MODEL_001, 'kp': 40.0, 'ti': 8.0, 'robustness.ms_max': 2.0}
    controller = pid_kind.KIND.build(resolve(pid_kind.KIND, hand))
    assert pid_kind.KIND.results(controller)['robustness.warning'] == ''
    worse = resolve(pid_kind.KIND, {**hand, 'tuning.dead_time': 6.0}, given={'tuning.dead_time'})
    pid_kind.KIND.update(controller, worse, frozenset({'tuning.dead_time'}))
    results = pid_kind.KIND.results(controller)
    report = loop_report(ProcessModel('fopdt', 0.05, 6.0, 10.0), PidConfig(kp=40.0, ti=8.0,
                                                                           sample_time=0.1))
    assert results['robustness.model'] == 'fopdt K=0.05 T=10 s L=6 s'
    assert results['robustness.ms'] == pytest.approx(report.ms)
    assert ('unstable' in results['robustness.warning'] if not report.stable
            else f'Ms {report.ms:.3g} > robustness.ms_max 2' in results['robustness.warning'])


def test_results_without_a_model_are_none_and_valid_parameters():
    kind = pid_kind.KIND
    controller = kind.build(resolve(kind, {'kp': 2.0}))
    results = kind.results(controller)
    assert results['robustness.model'] == 'none' and results['robustness.ms'] == 0.0
    specs = {s.name: s for s in kind.specs()}
    assert not [specs[k].check(v) for k, v in results.items() if specs[k].check(v)]
    controller = kind.build(resolve(kind, {**MODEL_001, **ZN_001}))
    results = kind.results(controller)
    assert not [specs[k].check(v) for k, v in results.items() if specs[k].check(v)]
    assert results['robustness.stable'] is True
    assert results['robustness.ms'] == pytest.approx(2.73, abs=0.005)
    assert results['robustness.gain_margin'] == pytest.approx(1.59, abs=0.005)
    assert results['robustness.delay_margin'] == pytest.approx(2.08, abs=0.005)


def test_relay_autotune_guard_uses_the_identified_model():
    """relay_autotune: the model is the one in autotune.model_* (written back after a test)."""
    identified = {'autotune.model_kind': 'fopdt', 'autotune.model_gain': 0.05,
                  'autotune.model_time_constant': 10.0, 'autotune.model_dead_time': 3.0,
                  'sample_time': 0.1, 'robustness.ms_max': 2.0}
    with pytest.raises(ConfigError, match='kp, ti, td: Ms would be'):
        resolve(relay_kind.KIND, {**identified, **ZN_001}, given={'kp', 'ti', 'td'})
    resolve(relay_kind.KIND, {**identified, **ZN_001, 'autotune.model_kind': 'none'},
            given={'kp', 'ti', 'td'})
    with pytest.raises(ConfigError, match="autotune.rule 'simc' with autotune.kind 'pid'"):
        resolve(relay_kind.KIND, {**identified, 'autotune.rule': 'simc'},
                given={'autotune.rule'})
    assert math.isfinite(resolve(relay_kind.KIND, {**identified, 'autotune.rule': 'amigo'},
                                 given={'autotune.rule'}).values['kp'])
