"""The auto-tuning chain of RelayAutotuner without ROS: identify → design (rule and target) →
preview → apply → verify → revert, on [DeadTimeNotes]'s FOPDT (K = 0.05, T = 10 s, L = 3 s) integrated
exactly by test/support/relay.py.

Expected values are derived independently: the design from ``tune`` on the reported model,
the prediction by simulating the implemented PID on the exact plant, bumplessness from the
output sequence."""
from __future__ import annotations

import numpy as np
import pytest
from support.relay import ExactDelayPlant, closed_loop

from tank_control.core.analysis.robustness import loop_report
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import AutotuneConfig, RelayAutotuner
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.tuning.rules import tune

K, T, L, R, U0 = 0.05, 10.0, 3.0, 100.0, 2000.0
BEFORE = dict(kp=20.0, ti=12.0, td=0.0)
H = 0.1


def tuner_with(**autotune) -> RelayAutotuner:
    cfg = AutotuneConfig(**{'relay_amplitude': 200.0, 'settle_time': 5.0, 'settle_band': 0.5,
                            'rule': 'ms', 'kind': 'pid', **autotune})
    tuner = RelayAutotuner(PidConfig(sample_time=H, u_min=0.0, u_max=1e4, **BEFORE), cfg)
    tuner.reset(np.array([R]), np.array([U0]))
    return tuner


def run(tuner, samples, actions=None, setpoint=R, plant=None, noise=0.0):
    """``actions``: {sample index: callable(tuner, plant)} done before that sample."""
    plant = plant or ExactDelayPlant(K, T, L, y0=R, u0=U0)
    actions = {10: lambda tu, p: tu.start(), **(actions or {})}

    def before(k: int, t: float) -> None:
        if k in actions:
            actions[k](tuner, plant)
    log = closed_loop(tuner, plant, setpoint, samples, noise, seed=3, before_step=before)
    return log, plant


def model_of(tuner) -> ProcessModel:
    return tuner.model


def test_preview_proposes_without_changing_the_running_gains():
    tuner = tuner_with(apply='preview')
    log, _ = run(tuner, 1500)
    assert tuner.state == 'proposed'
    cfg = tuner.pid.config
    assert (cfg.kp, cfg.ti, cfg.td) == (20.0, 12.0, 0.0)
    p = tuner.proposal
    m = tuner.model
    expected = tune('ms', 'pid', model='fopdt', gain=m.gain, time_constant=m.time_constant,
                    dead_time=m.dead_time, ms=1.4, sample_time=H, filter_n=10.0)
    assert p.gains['kp'] == pytest.approx(expected['kp'])
    assert p.gains['ti'] == pytest.approx(expected['ti'])
    assert p.report.ms == pytest.approx(1.4, rel=1e-3)
    res = tuner.results()
    assert res['autotune.proposed_kp'] == pytest.approx(expected['kp'])
    assert res['autotune.proposed_ms'] == pytest.approx(p.report.ms)
    assert res['autotune.predicted_iae_load'] == pytest.approx(p.prediction.iae_load)
    assert res['autotune.verify_state'] == 'none' and res['autotune.warning'] == ''
    # the identified model is close to the plant: on the true plant the design's Ms is 1.4 ± 3 %
    true = loop_report(ProcessModel('fopdt', K, L, T), PidConfig(sample_time=H, **{
        k: v for k, v in p.gains.items()}))
    assert true.ms == pytest.approx(1.4, rel=0.03)


def test_apply_and_revert_are_bumpless_and_exact():
    tuner = tuner_with(apply='preview')
    outputs: dict[str, float] = {}

    def apply(tu, plant):
        outputs['before_apply'] = tu._last_out
        assert tu.apply()[0]

    def revert(tu, plant):
        outputs['before_revert'] = tu._last_out
        assert tu.revert()[0]
    log, _ = run(tuner, 3000, {1800: apply, 2400: revert})
    k_apply, k_revert = 1800, 2400
    assert log['state'][k_apply] == 'running' and log['state'][k_revert] == 'reverted'
    # bumpless: at rest, the output at the switching sample continues the previous one
    for k in (k_apply, k_revert):
        assert abs(log['u'][k] - log['u'][k - 1]) < 1e-6 * U0
    cfg = tuner.pid.config
    assert (cfg.kp, cfg.ti, cfg.td) == (20.0, 12.0, 0.0)
    assert tuner.apply()[0] and tuner.state == 'running'   # the proposal remains


def test_apply_is_refused_without_a_proposal_and_beyond_ms_max():
    tuner = tuner_with(apply='preview')
    ok, message = tuner.apply()
    assert not ok and 'no proposal' in message
    assert not tuner.revert()[0]
    run(tuner, 1500)
    tuner.ms_max = 1.2
    ok, message = tuner.apply()
    assert not ok and 'Ms would be 1.4 > robustness.ms_max 1.2' in message
    assert tuner.pid.config.kp == 20.0


def test_auto_apply_is_refused_beyond_ms_max_and_reported():
    tuner = tuner_with(apply='auto', rule='zn_001')
    tuner.ms_max = 2.0
    run(tuner, 1500)
    assert tuner.state == 'proposed' and tuner.pid.config.kp == 20.0
    assert 'proposal not applied: Ms would be' in tuner.results()['autotune.warning']


def test_a_rule_change_re_derives_the_gains_from_the_stored_model():
    """No new relay test: the gains follow the rule and target on the kept model."""
    tuner = tuner_with(apply='auto')
    log, _ = run(tuner, 1500)
    assert tuner.state == 'running'
    model = tuner.model
    tuner.configure(AutotuneConfig(relay_amplitude=200.0, settle_time=5.0, settle_band=0.5,
                                   rule='ms', kind='pi', ms_target=1.6))
    expected = tune('ms', 'pi', model='fopdt', gain=model.gain, time_constant=model.time_constant,
                    dead_time=model.dead_time, ms=1.6, sample_time=H, filter_n=10.0)
    cfg = tuner.pid.config
    assert (cfg.kp, cfg.ti, cfg.td) == pytest.approx((expected['kp'], expected['ti'], 0.0))
    assert tuner.state == 'running' and tuner.model is model
    tuner.configure(AutotuneConfig(relay_amplitude=200.0, settle_time=5.0, settle_band=0.5,
                                   rule='amigo', kind='pid', apply='preview'))
    assert tuner.state == 'proposed' and tuner.pid.config.kp == pytest.approx(expected['kp'])
    amigo = tune('amigo', 'pid', gain=model.gain, time_constant=model.time_constant,
                 dead_time=model.dead_time)
    assert tuner.proposal.gains['kp'] == pytest.approx(amigo['kp'])
    with pytest.raises(ValueError, match='second-order'):
        tuner.configure(AutotuneConfig(rule='simc', kind='pid'))
    assert tuner.config.rule == 'amigo'                         # unchanged on refusal


def test_verification_step_matches_the_prediction_on_a_matching_plant():
    """Noise-free, the plant equals the identified model to identification accuracy: the
    verified step's overshoot and IAE are the predicted ones within 5 %; the internal step is
    removed after the window, so the setpoint returns."""
    tuner = tuner_with(apply='auto', verify_step=5.0)
    log, _ = run(tuner, 4000)
    res = tuner.results()
    assert res['autotune.verify_state'] == 'ok', res['autotune.warning']
    assert res['autotune.verify_step_size'] == 5.0
    assert res['autotune.verify_iae_measured'] == pytest.approx(res['autotune.verify_iae_predicted'],
                                                                rel=0.05)
    assert res['autotune.verify_overshoot_measured'] == pytest.approx(
        res['autotune.verify_overshoot_predicted'], abs=2.0)
    assert abs(log['y'][-1] - R) < 0.5      # back at the user's setpoint


def test_verification_reports_a_response_much_worse_than_predicted():
    """The dead time grows from 3 to 5 s after the test; the next setpoint change is much
    worse than predicted and the warning gives the numbers."""
    tuner = tuner_with(apply='auto')

    def slower(tu, plant):
        plant.dead_time = 5.0
    run(tuner, 4500, {1500: slower}, setpoint=lambda t: R if t < 250.0 else R + 4.0)
    res = tuner.results()
    assert res['autotune.verify_state'] == 'worse'
    assert (res['autotune.verify_overshoot_measured']
            > 1.5 * res['autotune.verify_overshoot_predicted'] + 5.0)
    assert res['autotune.verify_iae_measured'] > res['autotune.verify_iae_predicted']
    warning = res['autotune.warning']
    assert 'much worse than predicted' in warning
    assert f"overshoot {res['autotune.verify_overshoot_measured']:.1f} %" in warning
    assert f"IAE {res['autotune.verify_iae_measured']:.4g}" in warning
    assert f"(predicted {res['autotune.verify_iae_predicted']:.4g})" in warning


def test_verification_on_the_next_setpoint_change():
    """Without a verification step the next setpoint change is measured."""
    tuner = tuner_with(apply='auto')
    log, _ = run(tuner, 4500, setpoint=lambda t: R if t < 250.0 else R + 4.0)
    res = tuner.results()
    assert res['autotune.verify_state'] == 'ok', res['autotune.warning']
    assert res['autotune.verify_step_size'] == pytest.approx(4.0)
    assert res['autotune.verify_iae_measured'] == pytest.approx(
        res['autotune.verify_iae_predicted'], rel=0.05)
