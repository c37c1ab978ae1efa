"""The auto-tuned Smith predictor ([Precup2013] §3.6, [Precup2013] §3.6–2.13) on exact plants: relay →
ZN PI → kP from a setpoint change → eq. 3.6.2 → Smith PI by eq. 3.6.7 (n = 1) or 3.6.9 (n = 2),
and the response the design predicts (eqs. 3.6.6, 3.6.8); abort and failures restore the Smith
predictor from before. Exact ultimate points are solved independently (support.relay)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from support.relay import ExactDelayPlant, exact_fopdt_ultimate

from tank_control.core.control.kinds import smith_pi as smith_kind
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import AutotuneConfig
from tank_control.core.control.smith import SmithModel
from tank_control.core.control.smith_autotune import (SmithAutotuner, SmithDesign, process_gain,
                                                      smith_model, smith_primary)
from tank_control.core.tuning.model import ProcessModel

H = 0.1


def loop(tuner, plant, setpoint, duration, actions=None):
    """Tuner and plant for ``duration`` s; ``actions[k]`` acts before sample k. Returns t, y,
    r, u, state and the [(t, state)] changes."""
    out = {'t': [], 'y': [], 'r': [], 'u': [], 'state': []}
    for k in range(int(round(duration / H))):
        t = k * H
        y = float(plant.outputs()[0])
        r = setpoint(t)
        if actions and k in actions:
            actions[k]()
        u = float(tuner.step(t, np.array([y]), np.array([r]), np.zeros(0))[0])
        for key, value in zip(out, (t, y, r, u, tuner.state)):
            out[key].append(value)
        plant.step(np.array([u]), np.zeros(len(getattr(plant, 'disturbance_names', ()))), H)
    res = {k: np.array(v) for k, v in out.items()}
    states = res['state']
    res['log'] = [(res['t'][i], states[i]) for i in range(len(states))
                  if i == 0 or states[i] != states[i - 1]]
    return res


CHAIN = ['idle', 'settling', 'relay', 'measuring', 'waiting', 'process_gain', 'tuned',
         'running']


def test_eq_3_6_2_checks_of_the_supplement():
    """[Precup2013] §3.6: [DeadTimeNotes]'s plant n = 1 from ku 117.80, Tu 10.824 s gives T 10.000 s,
    Tm 3.000 s; (1, T 5 s, Tm 2 s) n = 2 from ku 5.6838, Tu 14.516 s gives T 5.000, Tm 2.000."""
    m1 = smith_model(117.80, 10.824, 0.05, 1)
    assert (m1.model, m1.time_constant, m1.dead_time) == ('fopdt', pytest.approx(10.0, abs=5e-3),
                                                           pytest.approx(3.0, abs=5e-3))
    m2 = smith_model(5.6838, 14.516, 1.0, 2)
    assert m2.model == 'sopdt' and m2.time_constant2 == m2.time_constant
    assert (m2.time_constant, m2.dead_time) == (pytest.approx(5.0, abs=5e-3),
                                                pytest.approx(2.0, abs=5e-3))
    assert process_gain(100.0, 110.0, 2000.0, 2200.0) == pytest.approx(0.05)
    with pytest.raises(ValueError, match='did not change'):
        process_gain(100.0, 110.0, 2000.0, 2000.0)
    # eq. 3.6.7: kR = T/(kP·Te), Ti = T; eq. 3.6.9: kR = 1/(4ξ²kP), Ti = T
    pi1 = smith_primary(m1, SmithDesign(1, te=5.0), PidConfig(sample_time=0.1))
    assert (pi1.kp, pi1.ti) == pytest.approx((m1.time_constant / (0.05 * 5.0), m1.time_constant))
    pi2 = smith_primary(m2, SmithDesign(2, xi=0.7), PidConfig(sample_time=0.1))
    assert (pi2.kp, pi2.ti) == pytest.approx((1.0 / (4 * 0.49), m2.time_constant))


def tuner_for(guess: SmithModel, kp: float, ti: float, design: SmithDesign, **autotune):
    cfg = AutotuneConfig(**{'relay_amplitude': 0.2, 'settle_time': 20.0, 'settle_band': 0.005,
                            'start_time': 20.0, **autotune})
    tuner = SmithAutotuner(guess, PidConfig(kp=kp, ti=ti, sample_time=H), cfg, design)
    tuner.reset(np.array([0.0]), np.array([0.0]))
    return tuner


def first_order_prediction(run, t_step, dead_time, te, r0, step):
    """[Precup2013] eq. 3.6.6 delayed by the dead time: the Smith loop's setpoint response."""
    tt = run['t'] - t_step - dead_time      # u moves at the step's sample (P kick, b = 1)
    return r0 + step * np.where(tt > 0, 1 - np.exp(-np.maximum(tt, 0) / te), 0.0)


@pytest.mark.parametrize('plant_args, guess, te, steps, relay', [
    ((0.05, 10.0, 3.0), SmithModel('fopdt', 0.05, 12.0, 3.5), 5.0, (10.0, 5.0), 200.0),  # [DeadTimeNotes]
    ((1.0, 2.0, 10.0), SmithModel('fopdt', 1.0, 3.0, 9.0), 1.0, (0.2, 0.1), 0.2),  # L/T = 5
], ids=['001_fopdt', 'dead_time_dominant'])
def test_chain_n1_recovers_the_fopdt_and_follows_eq_3_6_6(plant_args, guess, te, steps, relay):
    """The Smith predictor before the test is a guess (primary detuned: te doubled)."""
    k, t_c, dead = plant_args
    plant = ExactDelayPlant(k, t_c, dead)
    s1, s2 = steps
    tuner = tuner_for(guess, guess.time_constant / (guess.gain * 2 * te), guess.time_constant,
                      SmithDesign(1, te=te), relay_amplitude=relay, settle_band=0.02 * s1)
    w = lambda t: s1 * (t >= 300.0) + s2 * (t >= 700.0)      # noqa: E731
    run = loop(tuner, plant, w, 900.0)
    assert [s for _, s in run['log']] == CHAIN, tuner.status['reason']
    ku, tu = exact_fopdt_ultimate(k, t_c, dead)
    assert tuner.status['ku'] == pytest.approx(ku, rel=0.01)
    assert tuner.status['tu'] == pytest.approx(tu, rel=0.01)
    m = tuner.model
    assert m.model == 'fopdt'
    assert m.gain == pytest.approx(k, rel=0.02)
    assert m.time_constant == pytest.approx(t_c, rel=0.03)
    assert m.dead_time == pytest.approx(dead, abs=0.1)
    assert (tuner.primary.config.kp, tuner.primary.config.ti) == pytest.approx(
        (m.time_constant / (m.gain * te), m.time_constant))
    # the hand-over ZN PI → Smith PI is bumpless: no step in u beyond the PI's own motion
    i = int(np.argmax(run['state'] == 'tuned'))
    assert abs(run['u'][i] - run['u'][i - 1]) < 0.002 * abs(s1 / k)
    # the tuned loop follows the second step as eq. 3.6.6 predicts, delayed by the dead time
    sel = run['t'] >= 700.0
    pred = first_order_prediction({'t': run['t'][sel]}, 700.0, dead, te, s1, s2)
    assert np.abs(run['y'][sel] - pred).max() < 0.03 * s2
    res = tuner.results()
    assert res['autotune.model_method'] == 'eq_3_6_2' and res['smith.gain'] == m.gain


def test_chain_n2_on_a_dead_time_dominant_sopdt_follows_eq_3_6_8():
    """(1, T = 2 s double lag, Tm = 8 s): n = 2 recovers T and Tm; the Smith PI of eq. 3.6.9
    (ξ = 0.7) follows a setpoint step as eq. 3.6.8's second order, delayed."""
    k, t_c, dead, xi = 1.0, 2.0, 8.0, 0.7
    plant = ProcessModel('sopdt', k, dead, t_c, t_c).plant()
    guess = SmithModel('sopdt', 1.0, 3.0, 7.0, time_constant2=3.0)
    tuner = tuner_for(guess, 1.0 / (4 * xi * xi), 3.0, SmithDesign(2, xi=xi),
                      settle_band=0.004)
    w = lambda t: 0.2 * (t >= 300.0) + 0.1 * (t >= 700.0)      # noqa: E731
    run = loop(tuner, plant, w, 900.0)
    assert [s for _, s in run['log']] == CHAIN, tuner.status['reason']
    m = tuner.model
    assert m.model == 'sopdt' and m.time_constant2 == m.time_constant
    assert m.gain == pytest.approx(k, rel=0.02)
    assert m.time_constant == pytest.approx(t_c, rel=0.05)
    assert m.dead_time == pytest.approx(dead, abs=0.15)
    assert tuner.primary.config.kp == pytest.approx(1 / (4 * xi * xi * m.gain))
    sel = run['t'] >= 700.0
    w0 = 1.0 / (2 * xi * m.time_constant)
    wd = w0 * math.sqrt(1 - xi * xi)
    tt = np.maximum(run['t'][sel] - 700.0 - dead, 0.0)
    pred = 0.2 + 0.1 * (1 - np.exp(-xi * w0 * tt) * (np.cos(wd * tt) + xi / math.sqrt(1 - xi * xi)
                                                      * np.sin(wd * tt)))
    assert np.abs(run['y'][sel] - pred).max() < 0.03 * 0.1


def smith_at_rest():
    guess = SmithModel('fopdt', 1.0, 3.0, 9.0)
    return tuner_for(guess, 1.5, 3.0, SmithDesign(1, te=1.0), start_time=0.0), guess


def test_abort_during_the_relay_restores_the_smith_predictor_bumplessly():
    tuner, guess = smith_at_rest()
    before = tuner.smith
    plant = ExactDelayPlant(1.0, 2.0, 10.0)
    run = loop(tuner, plant, lambda t: 0.5, 400.0,
               actions={0: tuner.start, 1500: lambda: tuner.abort('operator')})
    states = [s for _, s in run['log']]
    assert states[:3] == ['settling', 'relay', 'measuring'] and states[-1] == 'aborted'
    assert tuner.status['reason'] == 'operator' and tuner.relay is None
    assert tuner.smith is before and tuner.model == guess
    # the Smith predictor resumes from the relay's bias u0 (≈ 0.5), not from u0 ± d
    assert run['u'][1500] == pytest.approx(0.5, abs=0.01)
    assert abs(run['y'][-1] - 0.5) < 0.005
    assert tuner.results()['autotune.model_kind'] == 'none'


def test_failures_restore_the_smith_predictor_and_say_why():
    # a setpoint change during the relay
    tuner, guess = smith_at_rest()
    run = loop(tuner, ExactDelayPlant(1.0, 2.0, 10.0), lambda t: 0.5 + 0.1 * (t >= 100.0), 300.0,
               actions={0: tuner.start})
    assert run['log'][-1][1] == 'failed'
    assert tuner.status['reason'] == 'relay test: setpoint changed during the test'
    assert tuner.model == guess and abs(run['y'][-1] - 0.6) < 0.01
    # no steady response within autotune.timeout after the setpoint step (the relay phase
    # takes about 100 s of it, the transient about 200 s)
    tuner, guess = smith_at_rest()
    tuner.configure(AutotuneConfig(relay_amplitude=0.2, settle_time=20.0, settle_band=0.005,
                                   timeout=150.0))
    run = loop(tuner, ExactDelayPlant(1.0, 2.0, 10.0), lambda t: 0.3 * (t >= 300.0), 700.0,
               actions={0: tuner.start})
    assert [s for _, s in run['log']] == ['settling', 'relay', 'measuring', 'waiting',
                                          'process_gain', 'failed']
    assert tuner.status['reason'] == ('no steady response to the setpoint step within '
                                      'autotune.timeout = 150 s')
    assert tuner.model == guess and abs(run['y'][-1] - 0.3) < 0.005
    # start refused without the design target; refused while running
    tuner, _ = smith_at_rest()
    tuner.design = SmithDesign(1, te=0.0)
    ok, msg = tuner.start()
    assert not ok and 'tuning.te' in msg
    tuner.design = SmithDesign(2, xi=0.0)
    assert 'tuning.xi' in tuner.start()[1]


def test_kind_parameters_services_and_results():
    kind = smith_kind.KIND
    names = {s.name for s in kind.specs()}
    assert {'autotune.relay_amplitude', 'autotune.settle_band', 'autotune.start_time',
            'autotune.state', 'autotune.reason', 'autotune.ku', 'autotune.model_gain',
            'autotune.start', 'smith.time_constant2'} <= names
    assert 'autotune.rule' not in names and set(kind.commands) == {'start_autotune',
                                                                   'abort_autotune'}
    values = {'smith.gain': 1.0, 'smith.time_constant': 3.0, 'smith.dead_time': 9.0,
              'sample_time': H, 'kp': 1.5, 'ti': 3.0, 'tuning.te': 1.0,
              'autotune.relay_amplitude': 0.2, 'autotune.settle_band': 0.005,
              'autotune.settle_time': 20.0}
    ctrl = kind.build(resolve(kind, values))
    assert kind.commands['abort_autotune'](ctrl)[0] is False
    assert kind.commands['start_autotune'](ctrl) == (True, 'autotune: test started (settling)')
    assert kind.results(ctrl)['autotune.state'] == 'settling'
    # a user's change during the chain aborts it
    kind.update(ctrl, resolve(kind, {**values, 'kp': 1.4}), frozenset({'kp'}))
    res = kind.results(ctrl)
    assert res['autotune.state'] == 'aborted'
    assert res['autotune.reason'] == 'parameters changed during the test'
    # results are valid parameter values (what the node writes back)
    resolve(kind, {**values, **{k: v for k, v in res.items() if k in names}}, given=())
