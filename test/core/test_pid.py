"""Unit behaviour of the discrete 2-DOF PID ([Viteckova] eq. 19, [Viteckova] eqs. 13–19)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.control.kinds import pid as pid_kind
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.pid import (
    Pid2Dof,
    PidConfig,
    PidController,
    default_tracking_time,
)
from tank_control.core.interfaces import Controller
from tank_control.core.params import ConfigError


def make(**kw) -> Pid2Dof:
    base = dict(kp=2.0, ti=10.0, td=2.0, n=10.0, b=1.0, c=1.0, sample_time=0.5)
    base.update(kw)
    return Pid2Dof(PidConfig(**base))


# ------------------------------------------------------------ setpoint kick
def _backward_difference_d(kp: float, td: float, n: float, h: float, e: list[float]) -> list[float]:
    """Tf·dD/dt + D = kp·td·de/dt with backward differences, Tf = td/n, written out
    directly: (Tf/h)·(D(k) − D(k−1)) + D(k) = (kp·td/h)·(e(k) − e(k−1)), starting at
    rest (D(−1) = 0, e(−1) = e(0): no kick on the first sample)."""
    tf, d, prev, out = td / n, 0.0, e[0], []
    for ek in e:
        d = (tf / h * d + kp * td / h * (ek - prev)) / (tf / h + 1.0)
        prev = ek
        out.append(d)
    return out


@pytest.mark.parametrize('h', [0.5, 0.05, 1e-4])
def test_standard_pid_initial_output_of_a_setpoint_step(h):
    """u(0) = kp·(b + c·td/(Tf + h))·w0 with Tf = td/n (backward-difference filter from
    rest); as h → 0 it tends to kp·(1 + n)·w0, [Viteckova] eq. 16 with Td/Tf = n, b = c = 1."""
    kp, td, w0 = 2.0, 2.0, 3.0
    for n in (5.0, 10.0, 20.0):
        for b, c in ((1.0, 1.0), (0.4, 0.6)):
            pid = make(n=n, b=b, c=c, sample_time=h)
            pid.reset(0.0, 0.0, 0.0)
            assert pid.update(w0, 0.0) == pytest.approx(kp * (b + c * td / (td / n + h)) * w0, rel=1e-12)
    pid = make(n=10.0, sample_time=h)
    pid.reset(0.0, 0.0, 0.0)
    assert pid.update(w0, 0.0) == pytest.approx(kp * (1 + 10.0) * w0, rel=2 * h / (td / 10.0))


def test_c_zero_removes_the_derivative_kick():
    """With c = 0 only the weighted P term reacts to a setpoint step ([Viteckova] eq. 18 with b)."""
    pid = make(b=0.4, c=0.0)
    pid.reset(0.0, 0.0, 0.0)
    assert pid.update(3.0, 0.0) == pytest.approx(2.0 * 0.4 * 3.0, rel=1e-12)


@pytest.mark.parametrize('h', [0.05, 0.5, 3.0])
def test_derivative_is_the_backward_difference_filter(h):
    """The D term (b = 0, no integral) follows the backward-difference equation of
    kp·td·s/(Tf·s + 1) for an arbitrary error sequence, also with h ≫ Tf = 0.2 s."""
    kp, td, n = 2.0, 2.0, 10.0
    rng = np.random.default_rng(3)
    e = [0.0] + list(np.cumsum(rng.normal(size=60)))
    pid = make(kp=kp, ti=math.inf, td=td, n=n, b=0.0, c=1.0, sample_time=h)
    pid.reset(0.0, 0.0, 0.0)
    u = [pid.update(ek, 0.0) for ek in e]
    assert u == pytest.approx(_backward_difference_d(kp, td, n, h, e), rel=1e-9, abs=1e-12)


@pytest.mark.parametrize('h', [0.01, 0.3, 1.0, 5.0])
def test_derivative_gain_at_low_frequency_is_exactly_kp_td(h):
    """A ramp error of slope a gives, once the filter has settled, D = kp·td·a — the
    continuous derivative's value — for any h, also h ≫ Tf (the step-invariant
    discretisation gave kp·td·a·x/(1 − e^(−x)), x = h/Tf). And the response to an error
    step has the area kp·td·w0 of the continuous filter's impulse kp·td·δ."""
    kp, td, n, a, w0 = 2.0, 1.3, 10.0, 0.7, 1.5
    pid = make(kp=kp, ti=math.inf, td=td, n=n, b=0.0, c=1.0, sample_time=h)
    pid.reset(0.0, 0.0, 0.0)
    steps = int(50 * (td / n + h) / h) + 2      # 50 filter time constants in samples
    u = [pid.update(a * k * h, 0.0) for k in range(steps)]
    assert u[-1] == pytest.approx(kp * td * a, rel=1e-9)
    pid = make(kp=kp, ti=math.inf, td=td, n=n, b=0.0, c=1.0, sample_time=h)
    pid.reset(0.0, 0.0, 0.0)
    area = sum(pid.update(w0, 0.0) for _ in range(steps)) * h
    assert area == pytest.approx(kp * td * w0, rel=1e-9)


def test_derivative_filter_is_stable_and_does_not_ring_for_tiny_tf():
    """Tf = 0.001 s with h = 1 s: the kick kp·td/(Tf + h)·w0 decays monotonically by
    β = Tf/(Tf + h) per sample, without changing sign (Tustin would ring here)."""
    kp, td, n, h = 2.0, 0.01, 10.0, 1.0
    pid = make(kp=kp, ti=math.inf, td=td, n=n, sample_time=h, b=0.0)
    pid.reset(0.0, 0.0, 0.0)
    outs = [pid.update(1.0, 0.0) for _ in range(5)]
    tf = td / n
    assert outs[0] == pytest.approx(kp * td / (tf + h), rel=1e-12)
    beta = tf / (tf + h)
    for k, u in enumerate(outs):
        assert u == pytest.approx(outs[0] * beta ** k, rel=1e-6, abs=1e-12)
        assert u >= -1e-12


# ----------------------------------------------------------------- integral
def test_pi_ramp_with_constant_error():
    """Forward-Euler integral: u(k) = kp·e·(1 + k·h/ti) for a constant error e."""
    kp, ti, h, e = 2.0, 10.0, 0.5, 1.5
    pid = make(kp=kp, ti=ti, td=0.0, sample_time=h)
    pid.reset(0.0, 0.0, 0.0)
    for k in range(20):
        assert pid.update(e, 0.0) == pytest.approx(kp * e * (1 + k * h / ti), rel=1e-12)


def test_ti_inf_is_p_only_with_bias_from_reset():
    pid = make(ti=math.inf, td=0.0)
    pid.reset(1.0, 1.0, 7.0)
    for _ in range(5):
        assert pid.update(2.0, 1.0) == pytest.approx(7.0 + 2.0 * 1.0)


def test_negative_kp_and_direct_action_reverse_the_sign():
    neg = make(kp=-2.0, td=0.0)
    direct = make(kp=2.0, td=0.0, direct_action=True)
    for pid in (neg, direct):
        pid.reset(0.0, 0.0, 0.0)
    for _ in range(5):
        a, b = neg.update(1.0, 3.0), direct.update(1.0, 3.0)
        assert a > 0 and a == pytest.approx(b)


# --------------------------------------------------------- bumpless changes
def _settled_pair(**kw):
    """Two identical controllers after 400 samples at constant r, y (D settled)."""
    a, b = make(**kw), make(**kw)
    for pid in (a, b):
        pid.reset(0.0, 0.0, 1.0)
        for _ in range(400):
            pid.update(2.0, 1.5)
    return a, b


@pytest.mark.parametrize('change', [
    dict(kp=5.0), dict(ti=3.0), dict(td=0.5), dict(n=4.0), dict(b=0.2), dict(c=0.0),
    dict(kp=0.5, ti=40.0, td=0.0, b=0.0, c=0.3),
])
def test_gain_change_is_bumpless(change):
    """After a change the next output equals the unchanged controller's next output."""
    a, b = _settled_pair(ti=1e6)
    b.set_gains(**change)
    assert b.update(2.0, 1.5) == pytest.approx(a.update(2.0, 1.5), abs=1e-9)


def test_c_change_does_not_disturb_the_derivative_mid_transient():
    a, b = make(), make()
    for pid in (a, b):
        pid.reset(0.0, 0.0, 0.0)
        pid.update(1.0, 0.0)
    b.set_gains(c=0.5)
    assert b.update(1.0, 0.0) == pytest.approx(a.update(1.0, 0.0), rel=1e-12)


def test_invalid_gain_change_is_rejected_and_leaves_controller_untouched():
    a, b = make(), make()
    for pid in (a, b):
        pid.reset(0.0, 0.0, 0.0)
        pid.update(1.0, 0.2)
    for bad, name in ((dict(ti=-1.0), 'ti'), (dict(n=1.0), 'n'), (dict(b=2.0), 'b'),
                      (dict(kp=math.nan), 'kp'), (dict(u_min=5.0, u_max=1.0), 'u_min'),
                      (dict(gain=1.0), 'gain'), (dict(anti_windup='x'), 'anti_windup')):
        with pytest.raises(ValueError, match=name):
            b.set_gains(**bad)
    assert b.config == a.config
    assert b.update(1.0, 0.3) == a.update(1.0, 0.3)


def test_manual_auto_transfer_is_bumpless_both_ways():
    pid = make(td=1.0)
    pid.reset(0.0, 0.0, 0.0)
    for _ in range(10):
        u_auto = pid.update(1.0, 0.2)
    pid.set_manual()                       # auto → manual: hold
    assert pid.update(1.0, 0.3) == u_auto
    pid.set_manual(4.0)
    for y in (0.3, 0.5, 0.9):              # measurement moves while in manual
        assert pid.update(1.5, y) == 4.0
    assert pid.status['mode'] == 'manual'
    pid.set_auto()                         # manual → auto: continue at 4.0
    assert pid.update(1.5, 0.9) == pytest.approx(4.0, abs=1e-12)
    assert pid.status['mode'] == 'auto'


def test_reset_gives_no_derivative_spike():
    pid = make()
    pid.reset(0.0, 0.0, 0.0)
    for _ in range(5):
        pid.update(1.0, 0.0)
    pid.reset(10.0, 3.0, 2.5)              # new setpoint and measurement
    assert pid.update(10.0, 3.0) == pytest.approx(2.5, abs=1e-12)


def test_first_sample_without_reset_has_no_kick():
    pid = make(b=0.5)
    assert pid.update(4.0, 1.0) == pytest.approx(2.0 * (0.5 * 4.0 - 1.0))


# ------------------------------------------------------ limits and windup
def _integrator_loop(pid: Pid2Dof, steps: int, r: float = 1.0, k: float = 0.1):
    """Exact discrete integrator plant y' = k·u (ZOH, h = pid sample time)."""
    h = pid.config.sample_time
    y, ys, us = 0.0, [], []
    for _ in range(steps):
        u = pid.update(r, y)
        ys.append(y)
        us.append(u)
        y += k * h * u
    return np.array(ys), np.array(us)


def test_anti_windup_limits_overshoot_after_saturation():
    cfg = dict(kp=5.0, ti=5.0, td=0.0, sample_time=0.1, u_min=-1.0, u_max=1.0)
    over = {}
    for method in ('none', 'back_calculation', 'conditional_integration'):
        pid = make(**cfg, anti_windup=method)
        pid.reset(0.0, 0.0, 0.0)
        ys, us = _integrator_loop(pid, 800, r=5.0)
        assert us.max() <= 1.0 and us.min() >= -1.0
        if method != 'none':               # settled within 80 s; the wound-up loop is not
            assert abs(ys[-1] - 5.0) < 0.01
        over[method] = ys.max() - 5.0
    assert over['none'] > 1.0
    assert over['back_calculation'] < 0.25 * over['none']
    assert over['conditional_integration'] < 0.25 * over['none']


def test_back_calculation_status_reports_saturation():
    pid = make(kp=5.0, ti=5.0, td=0.0, u_max=1.0)
    pid.reset(0.0, 0.0, 0.0)
    pid.update(5.0, 0.0)
    assert pid.status['saturated'] and pid.status['anti_windup_active']
    assert default_tracking_time(9.0, 4.0) == pytest.approx(6.0)
    assert default_tracking_time(9.0, 0.0) == 9.0


def test_rate_limit_bounds_every_step():
    pid = make(td=0.0, du_max=2.0, sample_time=0.5)     # 1 unit per sample
    pid.reset(0.0, 0.0, 0.0)
    outs = [pid.update(5.0, 0.0) for _ in range(30)]
    steps = np.diff([0.0] + outs)
    assert np.all(np.abs(steps) <= 1.0 + 1e-12)
    assert outs[0] == pytest.approx(1.0)
    assert pid.status['rate_limited'] is False          # caught up with v by then


# ------------------------------------------------------------- bad inputs
def test_non_finite_input_holds_output_and_recovers_bumplessly():
    pid = make()
    pid.reset(0.0, 0.0, 0.0)
    for _ in range(5):
        last = pid.update(1.0, 0.2)
    for bad in (math.nan, math.inf, -math.inf):
        assert pid.update(1.0, bad) == last
        assert pid.update(bad, 0.2) == last
        assert pid.status['input_fault']
    assert pid.update(1.0, 0.2) == pytest.approx(last, abs=1e-12)
    assert not pid.status['input_fault']


def test_huge_inputs_keep_output_finite():
    pid = make(kp=1e6, td=1e6)
    pid.reset(0.0, 0.0, 0.0)
    for y in (1e300, -1e300, 1e308):
        assert math.isfinite(pid.update(0.0, y))


def test_invalid_config_is_rejected_with_the_parameter_name():
    for bad, name in ((dict(kp=0.0), 'kp'), (dict(n=60.0), 'n'), (dict(sample_time=0.0), 'sample_time'),
                      (dict(td=-1.0), 'td'), (dict(du_max=0.0), 'du_max'),
                      (dict(tracking_time=-2.0), 'tracking_time'), (dict(c=-0.1), 'c')):
        with pytest.raises(ValueError, match=name):
            make(**bad)


# ------------------------------------------------------- protocol adapter
def test_pid_controller_follows_the_controller_protocol():
    ctl = PidController(PidConfig(kp=2.0, ti=10.0, sample_time=0.5), output_name='h', input_name='F_H')
    assert isinstance(ctl, Controller)
    assert ctl.output_names == ('h',) and ctl.input_names == ('F_H',) and ctl.disturbance_names == ()
    assert ctl.sample_time == 0.5
    ctl.reset(np.array([3.0]), np.array([7.0]))
    u = ctl.step(0.0, np.array([3.0]), np.array([5.0]), np.array([]))
    assert u.shape == (1,) and u[0] == pytest.approx(7.0)   # bumpless: continues at u
    with pytest.raises(ValueError, match='y'):
        ctl.step(0.5, np.array([1.0, 2.0]), np.array([5.0]), np.array([]))
    assert 'mode' in ctl.status


# ------------------------------------------------------------ parameters
def reason(values: dict) -> str | None:
    """Why the pid kind refuses parameter ``values`` (None: accepted)."""
    try:
        resolve(pid_kind.KIND, values)
    except ConfigError as exc:
        return str(exc)
    return None


def test_param_specs_are_described_and_self_consistent():
    specs = pid_kind.KIND.specs()
    names = [s.name for s in specs]
    for required in ('sample_time', 'kp', 'ti', 'td', 'n', 'b', 'c', 'u_min', 'u_max', 'du_max',
                     'anti_windup', 'tracking_time', 'mode', 'manual_output', 'fail_safe_output',
                     'tuning.rule', 'tuning.kind', 'tuning.gain', 'tuning.dead_time',
                     'tuning.time_constant', 'tuning.ku', 'tuning.tu', 'initial_output',
                     'output_names', 'input_names'):
        assert required in names
    assert len(names) == len(set(names))
    for spec in specs:
        assert spec.description and spec.check(spec.default) is None
    assert reason({}) is None
    assert next(s for s in specs if s.name == 'kp').check(-1.0) is not None


def test_relations_are_checked_with_reasons():
    assert reason({'u_min': 5.0, 'u_max': 1.0}).startswith('u_min')
    assert reason({'kp': 0.0}).startswith('kp')
    assert reason({'u_min': 0.0, 'u_max': 10.0, 'manual_output': 20.0}).startswith('manual_output')
    assert reason({'u_min': 0.0, 'u_max': 10.0, 'fail_safe_output': 20.0}).startswith(
        'fail_safe_output')          # refused whether or not fail_safe = output is selected
    assert reason({'kpp': 2.0}) == 'kpp: unknown parameter; did you mean kp?'
    assert reason({'kp': 'abc'}).startswith("kp: 'abc' is a str")


def test_param_conventions_map_to_config():
    cfg = resolve(pid_kind.KIND, {'kp': 3.0, 'ti': 0.0, 'du_max': 0.0, 'tracking_time': 0.0}).config
    assert cfg.kp == 3.0 and math.isinf(cfg.ti) and math.isinf(cfg.du_max) and cfg.tracking_time is None


MDP = {'tuning.rule': 'mdp', 'tuning.kind': 'pid', 'tuning.gain': 0.05, 'tuning.dead_time': 5.0}


def test_tuning_parameters_give_the_gains_and_name_missing_ones():
    settings = resolve(pid_kind.KIND, MDP)
    cfg = settings.config
    assert cfg.kp == pytest.approx(3.134, abs=1e-3) and cfg.b == pytest.approx(0.423, abs=1e-3)
    assert settings.values['kp'] == cfg.kp                    # derived values are the parameters'
    assert 'tuning.dead_time' in reason({'tuning.rule': 'mdp', 'tuning.kind': 'pi',
                                         'tuning.gain': 0.05})
    assert 'kind' in reason({**MDP, 'tuning.kind': 'p'})


def test_a_gain_given_with_a_rule_must_agree_with_it_in_every_path():
    """One rule for files, --set and live changes: a gain the rule sets may be given only with
    the rule's value (a dump loads back); another value is refused, naming the gain and the
    rule, instead of being silently replaced."""
    kp = resolve(pid_kind.KIND, MDP).config.kp
    assert resolve(pid_kind.KIND, {**MDP, 'kp': kp}).config.kp == kp
    refused = reason({**MDP, 'kp': 1.0})
    assert refused.startswith('kp: 1 conflicts with tuning.rule') and 'mdp' in refused
    assert reason({**MDP, 'b': 1.0}).startswith('b: 1 conflicts')
    # a value given earlier and kept (not set in this change) is replaced by the derived one
    assert resolve(pid_kind.KIND, {**MDP, 'kp': 1.0}, given=('tuning.gain',)).config.kp == kp


def test_setpoint_weights_can_be_set_by_hand_with_the_rule_gains():
    """[Viteckova] Figs. 4-5: the MDP gains with b = c = 0 (tuning.setpoint_weights false)."""
    settings = resolve(pid_kind.KIND, {**MDP, 'tuning.setpoint_weights': False, 'b': 0.0,
                                       'c': 0.0})
    tuned = resolve(pid_kind.KIND, MDP).config
    assert (settings.config.b, settings.config.c) == (0.0, 0.0)
    assert (settings.config.kp, settings.config.ti, settings.config.td) == (
        tuned.kp, tuned.ti, tuned.td)


def test_classical_zn_rule_is_a_tuning_parameter_choice():
    """tuning.rule 'zn' (Ziegler–Nichols 1942: 0.6·Ku, Tu/2, Tu/8) through the parameters."""
    cfg = resolve(pid_kind.KIND, {'tuning.rule': 'zn', 'tuning.kind': 'pid', 'tuning.ku': 10.0,
                                  'tuning.tu': 4.0}).config
    assert (cfg.kp, cfg.ti, cfg.td, cfg.b, cfg.c) == pytest.approx((6.0, 2.0, 0.5, 1.0, 1.0))
    assert 'tuning.tu' in reason({'tuning.rule': 'zn', 'tuning.ku': 10.0})
