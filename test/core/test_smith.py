"""Smith predictor ([Precup2013] §3.6.1): with a perfect model the loop equals the delay-free loop, delayed."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.analysis.step_metrics import ise, step_metrics
from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds import smith_pi as smith_kind
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.pid import Pid2Dof, PidConfig
from tank_control.core.control.smith import SmithModel, SmithPredictor
from tank_control.core.interfaces import Controller
from tank_control.core.params import ConfigError
from tank_control.tuning import tune

SUB = 10      # plant substeps per controller sample (the plant's dead time is on this finer grid)


def run(controller_step, h, t_end, model, gain, dead_time, time_constant=None, w=None,
        v=lambda t: 0.0):
    """Exact plant on a grid of h/SUB: FOPDT or IPDT with the dead time a whole number of
    substeps, input held over each controller sample. Default setpoint: a unit step at the
    second sample (the first completes the controller's bumpless reset at r = 0).
    Returns the fine time grid and y."""
    if w is None:
        w = lambda t: 1.0 if t >= h - 1e-12 else 0.0     # noqa: E731
    dt = h / SUB
    nd = int(round(dead_time / dt))
    line = [0.0] * nd
    a = math.exp(-dt / time_constant) if model == 'fopdt' else 1.0
    y, ts, ys = 0.0, [], []
    u = 0.0
    for j in range(int(round(t_end / dt))):
        t = j * dt
        if j % SUB == 0:
            u = controller_step(t, y, w(t))
        ts.append(t)
        ys.append(y)
        line.append(u + v(t))
        x = line.pop(0)
        y = a * y + gain * (1 - a) * x if model == 'fopdt' else y + gain * dt * x
    return np.array(ts), np.array(ys)


def smith_config(model: str, gain: float, dead_time: float, kp: float, ti: float,
                 time_constant: float | None = None, sample_time: float = 1.0
                 ) -> tuple[SmithModel, PidConfig]:
    """The internal model and the PI primary of a Smith predictor."""
    return (SmithModel(model, gain, time_constant or 1.0, dead_time),
            PidConfig(kp=kp, ti=ti, sample_time=sample_time))


def smith_step(cfg):
    sp = SmithPredictor(*cfg)
    sp.reset(np.array([0.0]), np.array([0.0]))
    return lambda t, y, r: float(sp.step(t, np.array([y]), np.array([r]), np.array([]))[0])


def pi_step(kp, ti, h, b=1.0):
    pid = Pid2Dof(PidConfig(kp=kp, ti=ti, b=b, c=0.0, sample_time=h))
    pid.reset(0.0, 0.0, 0.0)
    return lambda t, y, r: pid.update(r, y)


@pytest.mark.parametrize('dead_time', [3.0, 3.5, 0.4])      # whole samples, half a sample, < 1 sample
def test_fopdt_perfect_model_equals_delayed_delay_free_loop(dead_time):
    k, t_c, h = 0.05, 10.0, 1.0
    g = tune('smith_pi', 'pi', gain=k, time_constant=t_c, te=4.0, n=1)
    cfg = smith_config(model='fopdt', gain=k, time_constant=t_c, dead_time=dead_time,
                      kp=g['kp'], ti=g['ti'], sample_time=h)
    ts, y_sp = run(smith_step(cfg), h, 60.0, 'fopdt', k, dead_time, t_c)
    _, y_free = run(pi_step(g['kp'], g['ti'], h), h, 60.0, 'fopdt', k, 0.0, t_c)
    shift = int(round(dead_time / (h / SUB)))
    assert np.abs(y_sp[shift:] - y_free[:len(y_free) - shift]).max() < 1e-9
    assert np.all(y_sp[:shift] == 0.0)


@pytest.mark.parametrize('dead_time', [5.0, 5.5])
def test_ipdt_perfect_model_equals_delayed_delay_free_loop(dead_time):
    k1, h = 0.05, 0.5
    kp, ti = 4.0, 20.0
    cfg = smith_config(model='ipdt', gain=k1, dead_time=dead_time, kp=kp, ti=ti, sample_time=h)
    ts, y_sp = run(smith_step(cfg), h, 80.0, 'ipdt', k1, dead_time)
    _, y_free = run(pi_step(kp, ti, h), h, 80.0, 'ipdt', k1, 0.0)
    shift = int(round(dead_time / (h / SUB)))
    assert np.abs(y_sp[shift:] - y_free[:len(y_free) - shift]).max() < 1e-9


def test_smith_pi_design_gives_first_order_like_response():
    """[Precup2013] eq. 3.6.6–7: closed loop ≈ e^(−L s)/(te·s + 1): no overshoot, 2 % settling ≈ L + 3.9·te."""
    k, t_c, dead, te, h = 0.05, 10.0, 3.0, 4.0, 0.1
    g = tune('smith_pi', 'pi', gain=k, time_constant=t_c, te=te, n=1)
    cfg = smith_config(model='fopdt', gain=k, time_constant=t_c, dead_time=dead,
                      kp=g['kp'], ti=g['ti'], sample_time=h)
    ts, y = run(smith_step(cfg), h, 60.0, 'fopdt', k, dead, t_c)
    m = step_metrics(ts, y, 1.0)
    assert m.overshoot < 0.5
    assert m.settling_time == pytest.approx(dead + te * math.log(50), rel=0.05)


def test_beats_plain_pi_on_a_dead_time_dominant_process():
    k, t_c, dead, h = 1.0, 5.0, 10.0, 0.5
    g = tune('smith_pi', 'pi', gain=k, time_constant=t_c, te=3.0, n=1)
    cfg = smith_config(model='fopdt', gain=k, time_constant=t_c, dead_time=dead,
                      kp=g['kp'], ti=g['ti'], sample_time=h)
    ts, y_sp = run(smith_step(cfg), h, 150.0, 'fopdt', k, dead, t_c)
    # plain PI tuned by Cohen–Coon for the same FOPDT (a fair, documented rule)
    cc = tune('cohen_coon', 'pi', gain=k, time_constant=t_c, dead_time=dead)
    _, y_pi = run(pi_step(cc['kp'], cc['ti'], h), h, 150.0, 'fopdt', k, dead, t_c)
    assert ise(ts, 1.0 - y_sp) < ise(ts, 1.0 - y_pi)
    assert step_metrics(ts, y_sp, 1.0).overshoot < step_metrics(ts, y_pi, 1.0).overshoot


@pytest.mark.parametrize('model', ['fopdt', 'ipdt'])
def test_plus_20_percent_dead_time_mismatch_stays_stable(model):
    h = 0.5
    if model == 'fopdt':
        k, t_c, dead = 0.05, 10.0, 3.0
        g = tune('smith_pi', 'pi', gain=k, time_constant=t_c, te=5.0, n=1)
        cfg = smith_config(model='fopdt', gain=k, time_constant=t_c, dead_time=dead,
                          kp=g['kp'], ti=g['ti'], sample_time=h)
    else:
        k, t_c, dead = 0.05, None, 5.0
        cfg = smith_config(model='ipdt', gain=k, dead_time=dead, kp=2.0, ti=40.0, sample_time=h)
    ts, y = run(smith_step(cfg), h, 200.0, model, k, 1.2 * dead, t_c)
    m = step_metrics(ts, y, 1.0)
    assert m.overshoot <= 20.0 and abs(m.steady_state_error) < 0.01


def test_ipdt_load_step_leaves_the_known_offset():
    """Documented limitation: constant input load v0 → steady error k1·L·v0 (classical SP, IPDT)."""
    k1, dead, h, v0 = 0.05, 5.0, 0.5, 0.2
    cfg = smith_config(model='ipdt', gain=k1, dead_time=dead, kp=2.0, ti=40.0, sample_time=h)
    ts, y = run(smith_step(cfg), h, 600.0, 'ipdt', k1, dead, w=lambda t: 0.0, v=lambda t: v0)
    assert (0.0 - y[-1]) == pytest.approx(-k1 * dead * v0, rel=1e-3)


def test_reset_is_bumpless_and_protocol():
    cfg = smith_config(model='fopdt', gain=2.0, time_constant=10.0, dead_time=3.0, kp=1.0, ti=10.0,
                      sample_time=1.0)
    sp = SmithPredictor(*cfg, output_name='T', input_name='Q')
    assert isinstance(sp, Controller) and sp.output_names == ('T',) and sp.input_names == ('Q',)
    sp.reset(np.array([8.0]), np.array([4.0]))
    assert sp.step(0.0, np.array([8.0]), np.array([9.0]), np.array([]))[0] == pytest.approx(4.0)
    held = sp.step(1.0, np.array([8.0]), np.array([9.0]), np.array([]))[0]
    assert sp.step(2.0, np.array([math.nan]), np.array([9.0]), np.array([]))[0] == held
    assert sp.status['input_fault']


def test_params_and_validation():
    kind = smith_kind.KIND
    for spec in kind.specs():
        assert spec.description and spec.check(spec.default) is None

    def reason(values: dict) -> str:
        with pytest.raises(ConfigError) as info:
            resolve(kind, values)
        return str(info.value)

    assert resolve(kind, {}).config == SmithModel()
    tuned = resolve(kind, {'tuning.rule': 'smith_pi', 'tuning.te': 4.0, 'smith.gain': 0.05,
                           'smith.time_constant': 10.0, 'smith.dead_time': 3.0}).primary
    assert tuned.kp == pytest.approx(10.0 / (0.05 * 4.0)) and tuned.ti == 10.0   # [Precup2013] eq. 3.6.7
    assert reason({'u_min': 1.0, 'u_max': 0.0}).startswith('u_min')
    assert reason({'tuning.rule': 'mdp'}).startswith('tuning.rule')
    # the internal model is first order: a rule for a second-order model is refused, not ignored
    assert reason({'tuning.rule': 'smith_pi', 'tuning.order': 2, 'tuning.xi': 0.7,
                   'smith.gain': 0.05, 'smith.time_constant': 10.0}).startswith('tuning.order')
    for bad, name in ((dict(model='x'), 'model'), (dict(gain=0.0), 'gain'),
                      (dict(dead_time=-1.0), 'dead_time'), (dict(time_constant=0.0), 'time_constant')):
        base = dict(model='fopdt', gain=1.0, time_constant=1.0, dead_time=1.0)
        base.update(bad)
        with pytest.raises(ValueError, match=name):
            SmithPredictor(SmithModel(**base), PidConfig(kp=1.0, ti=1.0))


def test_registered_as_smith_pi_kind_with_derived_gains_and_bumpless_rebuild():
    kind = registry.get_kind('smith_pi')
    values = {'tuning.rule': 'smith_pi', 'tuning.te': 4.0, 'smith.gain': 0.05,
              'smith.time_constant': 10.0, 'smith.dead_time': 3.0, 'output_names': ['T'],
              'input_names': ['Q']}
    settings = resolve(kind, values)
    assert settings.values['kp'] == pytest.approx(10.0 / (0.05 * 4.0))    # [Precup2013] eq. 3.6.7
    assert settings.values['ti'] == 10.0
    ctl = registry.build(kind, settings)
    assert ctl.output_names == ('T',) and ctl.input_names == ('Q',)
    y, r = np.array([0.0]), np.array([1.0])
    u = [ctl.step(float(k), y, r, np.array([]))[0] for k in range(3)]
    changed = resolve(kind, {**values, 'smith.dead_time': 4.0})
    new, u3 = registry.step_with_changes(kind, ctl, changed, frozenset({'smith.dead_time'}), 3.0,
                                         y, r, np.array([]))
    twin = registry.build(kind, settings)
    for k in range(4):
        u_twin = twin.step(float(k), y, r, np.array([]))[0]
    assert u[-1] is not None
    assert new is not ctl and u3[0] == pytest.approx(u_twin, abs=1e-12)   # old law at this sample
    # the rebuilt predictor starts from the steady state of u3 (prediction 0 here), so the next
    # output is u3 plus one integral increment kp·h/ti·e = 50·1/10·1
    assert new.step(4.0, y, r, np.array([]))[0] == pytest.approx(u3[0] + 5.0, abs=1e-9)
    manual_settings = resolve(kind, {**values, 'smith.dead_time': 4.0, 'mode': 'manual',
                                     'manual_output': 7.0})
    manual, _ = registry.step_with_changes(kind, new, manual_settings,
                                           frozenset({'mode', 'manual_output'}), 5.0, y, r,
                                           np.array([]))
    assert manual.step(6.0, y, r, np.array([]))[0] == 7.0


@pytest.mark.parametrize('t1, t2, dead_time', [(5.0, 5.0, 2.0), (5.0, 5.0, 3.7), (4.0, 1.5, 0.3)])
def test_sopdt_internal_model_is_the_exact_zoh_plant(t1, t2, dead_time):
    """The second-order internal model ([Precup2013] eq. 3.6.5, n = 2: T2 = T; distinct T2 too) against
    the project's exact SOPDT plant under a random held input: ŷ_L is the plant's output for
    any dead time (fractional ones included) and ŷ* the delay-free plant's."""
    from tank_control.core.tuning.model import DiscretePlant, ProcessModel
    h, k = 0.5, 1.3
    sp = SmithPredictor(SmithModel('sopdt', k, t1, dead_time, time_constant2=t2),
                        PidConfig(kp=1.0, ti=5.0, sample_time=h))
    sp.reset(np.array([0.0]), np.array([0.0]))
    sp.step(0.0, np.array([0.0]), np.array([0.0]), np.array([]))   # completes the reset (u = 0)
    sp._hist.appendleft(0.0)
    sp._hist.pop()
    plant = DiscretePlant(ProcessModel('sopdt', k, dead_time, max(t1, t2), min(t1, t2)), h)
    free = DiscretePlant(ProcessModel('sopdt', k, 0.0, max(t1, t2), min(t1, t2)), h)
    rng = np.random.default_rng(5)
    for u in rng.normal(size=80):
        assert sp._y_del == pytest.approx(plant.output(), abs=1e-9)
        assert sp._y_free == pytest.approx(free.output(), abs=1e-9)
        sp._advance(float(u))
        plant.step(float(u))
        free.step(float(u))


def test_sopdt_perfect_model_follows_eq_3_6_8_delayed():
    """n = 2, T2 = T, primary by [Precup2013] eq. 3.6.9 (kR = 1/(4ξ²kP), Ti = T): with a perfect model
    the loop is the delay-free loop delayed by L (whole samples), and at a small sample time
    that loop is eq. 3.6.8's second order with ω0 = 1/(2ξT)."""
    from tank_control.core.tuning.model import DiscretePlant, ProcessModel
    k, t_c, dead, xi, h = 1.0, 5.0, 2.0, 0.7, 0.01
    g = tune('smith_pi', 'pi', gain=k, time_constant=t_c, xi=xi, n=2)
    sp = SmithPredictor(SmithModel('sopdt', k, t_c, dead, time_constant2=t_c),
                        PidConfig(kp=g['kp'], ti=g['ti'], sample_time=h))
    sp.reset(np.array([0.0]), np.array([0.0]))
    plant = DiscretePlant(ProcessModel('sopdt', k, dead, t_c, t_c), h)
    n = int(round(40.0 / h))
    y = np.empty(n)
    for i in range(n):
        y[i] = plant.output()
        r = np.array([1.0 if i >= 1 else 0.0])     # the first sample completes the reset
        plant.step(float(sp.step(i * h, np.array([y[i]]), r, np.array([]))[0]))
    shift = int(round(dead / h)) + 1
    assert np.all(y[:shift + 1] == 0.0)
    w0 = 1.0 / (2.0 * xi * t_c)
    wd = w0 * math.sqrt(1 - xi * xi)
    tt = np.arange(n - shift) * h
    ideal = 1 - np.exp(-xi * w0 * tt) * (np.cos(wd * tt) + xi / math.sqrt(1 - xi * xi)
                                         * np.sin(wd * tt))
    assert np.abs(y[shift:] - ideal).max() < 0.01
    assert step_metrics(tt, y[shift:], 1.0).overshoot == pytest.approx(
        100 * math.exp(-math.pi * xi / math.sqrt(1 - xi * xi)), abs=0.3)


def test_kind_second_order_model_and_its_rule():
    """smith.model sopdt with smith.time_constant2 = smith.time_constant is [Precup2013]'s n = 2 model:
    tuning.rule smith_pi with tuning.order 2 designs eq. 3.6.9; the order must match the model."""
    kind = smith_kind.KIND
    base_values = {'smith.model': 'sopdt', 'smith.gain': 2.0, 'smith.time_constant': 5.0,
                   'smith.time_constant2': 5.0, 'smith.dead_time': 4.0, 'sample_time': 0.1,
                   'tuning.rule': 'smith_pi', 'tuning.order': 2, 'tuning.xi': 0.5}
    settings = resolve(kind, base_values)
    assert (settings.values['kp'], settings.values['ti']) == pytest.approx((1 / (4 * 0.25 * 2.0), 5.0))
    ctrl = kind.build(settings)
    assert kind.results(ctrl)['robustness.stable'] is True
    with pytest.raises(ConfigError, match='tuning.order: 2 designs for K/\\(T s\\+1\\)\\^2'):
        resolve(kind, {**base_values, 'smith.time_constant2': 2.0})
    with pytest.raises(ConfigError, match='tuning.order: 1 designs'):
        resolve(kind, {**base_values, 'tuning.order': 1, 'tuning.te': 2.0})
    with pytest.raises(ValueError, match='smith.time_constant2'):
        SmithPredictor(SmithModel('sopdt', 1.0, 5.0, 1.0, time_constant2=math.nan), PidConfig())


def test_a_predictor_unstable_on_its_own_model_is_refused_without_a_robustness_bound():
    """smith.gain of the sign opposite to kp: on the plant the predictor is designed for (its
    model) the loop diverges, so the kind refuses it (no robustness.ms_max needed) with its
    reason; the same numbers with the sign that matches kp run."""
    model, primary = smith_config('fopdt', -0.05, 3.0, kp=24.0, ti=12.0, time_constant=10.0,
                                  sample_time=0.1)
    _, y = run(smith_step((model, primary)), 0.1, 300.0, 'fopdt', -0.05, 3.0, 10.0)
    assert np.abs(y[-100:]).max() > 1e3 * np.abs(y[:300]).max()     # diverges on its model

    kind = registry.get_kind('smith_pi')
    values = {'smith.gain': -0.05, 'smith.time_constant': 10.0, 'smith.dead_time': 3.0,
              'kp': 24.0, 'ti': 12.0, 'sample_time': 0.1}
    with pytest.raises(ConfigError, match='on the plant it is designed for .* would be unstable'):
        resolve(kind, values)
    resolve(kind, {**values, 'smith.gain': 0.05})    # the same with the right sign runs
