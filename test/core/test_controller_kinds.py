"""Controller kinds (``core/control/kinds``): by name, tuning write-back, bumpless live updates.

``controller_setup`` is what controller_node and the in-process loop call with a node's
parameter values; ``registry.step_with_changes`` applies accepted live changes."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from tank_control.core import node_specs
from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind, resolve
from tank_control.core.interfaces import Controller
from tank_control.core.params import ConfigError, param
from tank_control.core.scenario import controller_setup


def make(values: dict) -> Controller:
    return controller_setup(values).build_controller()


def change(ctrl: Controller, values: dict, changed: set, t: float, y, r, d=np.array([])):
    """A live change as controller_node applies it at the sample at time t."""
    setup = controller_setup(values, given=())
    return registry.step_with_changes(setup.kind, ctrl, setup.settings, frozenset(changed), t,
                                      np.asarray(y, dtype=float), np.asarray(r, dtype=float), d)

K1, TO = 0.05, 5.0     # [Viteckova]'s worked example ([Viteckova] eq. 1)


def mdp_pid_closed_form(k1: float, to: float) -> dict[str, float]:
    """[Viteckova] eqs. 25–26, 32 ([Checks] §3), written out independently of the tuning module."""
    s3 = math.sqrt(3.0)
    return {'kp': 6 * (2 * s3 - 3) * math.exp(s3 - 3) / (k1 * to), 'ti': (2 + s3) * to,
            'td': (3 + s3) / 18 * to, 'b': (3 - s3) / 3, 'c': (3 - s3) / 2}


def step(ctrl: Controller, t: float, y: float, r: float) -> float:
    return float(ctrl.step(t, np.array([y]), np.array([r]), np.array([]))[0])


def test_pid_is_registered_with_controller_and_channel_params():
    assert 'pid' in registry.KINDS
    names = [s.name for s in node_specs.controller_specs('pid')]
    for name in ('controller', 'sample_time', 'kp', 'ti', 'td', 'n', 'b', 'c', 'u_min', 'u_max',
                 'du_max', 'anti_windup', 'tracking_time', 'mode', 'manual_output',
                 'fail_safe_output', 'tuning.rule', 'output_names', 'input_names'):
        assert name in names
    controller_spec = node_specs.controller_specs('pid')[0]
    assert controller_spec.read_only and controller_spec.default == 'pid'


def test_make_controller_builds_the_described_pid():
    ctrl = make({'controller': 'pid', 'kp': 2.0, 'b': 0.5, 'sample_time': 0.1,
                                     'output_names': ['h'], 'input_names': ['F_H']})
    assert isinstance(ctrl, Controller)
    assert ctrl.output_names == ('h',) and ctrl.input_names == ('F_H',)
    assert ctrl.sample_time == 0.1
    # P only (ti = 0 → no integral): u = kp·(b·r − y), [Viteckova] eq. 19
    assert step(ctrl, 0.0, 1.0, 4.0) == pytest.approx(2.0 * (0.5 * 4.0 - 1.0), abs=1e-12)


def test_runtime_parameters_of_the_node_are_accepted_and_ignored_in_process():
    ctrl = make({'kp': 2.0, 'clock_mode': 'lockstep', 'stale_samples': 5,
                                     'use_sim_time': True})
    assert step(ctrl, 0.0, 1.0, 2.0) == pytest.approx(2.0, abs=1e-12)
    with pytest.raises(ValueError, match='stale_samples'):
        make({'stale_samples': 0})
    with pytest.raises(ValueError, match='gain_typo: unknown parameter'):
        make({'gain_typo': 1.0})
    with pytest.raises(ValueError, match='kpp: unknown parameter; did you mean kp'):
        make({'kpp': 1.0})


@pytest.mark.parametrize('values, name', [
    ({'kp': -1.0}, 'kp'),
    ({'kp': 0.0}, 'kp'),
    ({'u_min': 5.0, 'u_max': 5.0}, 'u_min'),
    ({'n': 1.0}, 'n'),
    ({'controller': 'fuzzy'}, 'controller'),
    ({'tuning.rule': 'mdp', 'tuning.gain': 0.05}, 'dead_time'),   # missing process argument
])
def test_bad_values_rejected_with_a_reason_naming_the_parameter(values, name):
    with pytest.raises(ConfigError) as info:
        make(values)
    assert str(info.value).startswith(name) or f"'tuning.{name}'" in str(info.value)


def test_tuning_rule_gains_are_derived_and_used():
    values = {'tuning.rule': 'mdp', 'tuning.kind': 'pid', 'tuning.gain': K1, 'tuning.dead_time': TO}
    derived = controller_setup(values).settings.values
    expected = mdp_pid_closed_form(K1, TO)
    for name, value in expected.items():
        assert derived[name] == pytest.approx(value, rel=1e-12)
    ctrl = make(values)
    assert ctrl.pid.config.kp == pytest.approx(expected['kp'], rel=1e-12)
    # a hand-set gain that contradicts the rule is refused, not silently replaced
    with pytest.raises(ConfigError) as info:
        make({**values, 'kp': 2.0})
    assert str(info.value).startswith('kp:') and 'tuning.rule' in str(info.value)
    assert make({**values, **{k: derived[k] for k in expected}}) is not None


def test_live_gain_change_is_bumpless_and_then_in_effect():
    values = {'kp': 1.0, 'ti': 10.0, 'b': 0.5, 'sample_time': 1.0}
    ctrl = make(values)
    for k in range(3):                     # e = 0: the output is steady
        u_before = step(ctrl, float(k), 1.0, 1.0)
    values['kp'] = 3.0
    ctrl, u = change(ctrl, values, {'kp'}, 3.0, [1.0], [1.0])
    u_after = float(u[0])
    # a plain recomputation would jump by Δkp·(b·r − y) = 2·(−0.5) = −1
    assert u_after == pytest.approx(u_before, abs=1e-12)
    u_next = step(ctrl, 4.0, 1.1, 1.0)     # the new kp acts on the next error (P part)
    assert u_next - u_after == pytest.approx(-3.0 * 0.1, abs=1e-12)


class _Proportional:
    """A minimal Controller (u = u0 + gain·(r − y)) to exercise the registry hooks."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()

    def __init__(self, gain: float):
        self.gain = gain
        self.sample_time = 1.0
        self.u0 = 0.0
        self.pending = None

    def reset(self, y, u):            # completed at the next step, which knows r
        self.pending = (float(y[0]), float(u[0]))

    def step(self, t, y, r, d):
        if self.pending is not None:
            y0, u0 = self.pending
            self.u0, self.pending = u0 - self.gain * (float(r[0]) - y0), None
        return np.array([self.u0 + self.gain * (float(r[0]) - float(y[0]))])

    status = {'mode': 'auto'}


@dataclass(frozen=True)
class ProportionalConfig:
    gain: float = param(1.0, 'gain', unit='-', min=0.0, max=10.0)


PROPORTIONAL = ControllerKind(name='proportional', description='u = u0 + gain·(r − y)',
                              config=ProportionalConfig,
                              build=lambda settings: _Proportional(settings.config.gain))


def test_a_new_kind_is_one_table_line_and_rebuilt_bumplessly(monkeypatch):
    monkeypatch.setitem(registry.KINDS, 'proportional', PROPORTIONAL)
    with pytest.raises(ValueError, match='gain'):
        make({'controller': 'proportional', 'gain': 20.0})
    values = {'controller': 'proportional', 'gain': 1.0}
    ctrl = make(values)
    u = step(ctrl, 0.0, 1.0, 2.0)                                      # 0 + 1·(2 − 1)
    assert u == 1.0
    new, u1 = change(ctrl, {**values, 'gain': 4.0}, {'gain'}, 1.0, [1.5], [2.0])
    assert new is not ctrl and new.gain == 4.0
    assert u1[0] == pytest.approx(0.5, abs=1e-12)       # this sample: old gain on the new error
    assert step(new, 2.0, 1.0, 2.0) == pytest.approx(0.5 + 4.0 * 0.5, abs=1e-12)   # new gain


def test_two_loop_pi_registered_and_rebuilt_bumplessly_on_a_gain_change():
    values = {'controller': 'two_loop_pi'}
    ctrl = make(values)
    assert ctrl.output_names == ('h', 'T_out') and ctrl.input_names == ('F_H', 'F_Cin')
    y, r = np.array([80.0, 34.0]), np.array([81.0, 33.57])
    # [Michalski2021] §2.1 gains, first sample from zero integral: u = kp·e, clipped to 0…300
    u0 = ctrl.step(0.0, y, r, np.array([]))
    assert u0 == pytest.approx(np.clip([0.9 * 1.0, -0.2 * -0.43], 0, 300), abs=1e-12)
    twin = make(values)          # the same loop without the change
    twin.step(0.0, y, r, np.array([]))
    new, u1 = change(ctrl, {**values, 'two_loop.kp_h': 2.0}, {'two_loop.kp_h'}, 1.0, y, r)
    assert u1 == pytest.approx(twin.step(1.0, y, r, np.array([])), abs=1e-12)   # continuous
    y2 = np.array([79.5, 34.0])                       # h error 1 → 1.5: the new kp_h acts on it
    assert (new.step(2.0, y2, r, np.array([]))[0] - twin.step(2.0, y2, r, np.array([]))[0]
            == pytest.approx((2.0 - 0.9) * 0.5, abs=1e-9))
    with pytest.raises(ConfigError, match='fail_safe_output'):
        make({**values, 'fail_safe_output': [1.0]})


SMITH = {'controller': 'smith_pi', 'smith.gain': 0.05, 'smith.time_constant': 10.0,
         'smith.dead_time': 3.0, 'sample_time': 0.5}


def test_smith_pi_tuning_rule_and_bumpless_changes():
    values = {**SMITH, 'tuning.rule': 'smith_pi', 'tuning.te': 5.0}
    derived = controller_setup(values).settings.values
    # [Precup2013] eq. 3.6.7 (n = 1): kR = T/(kP·Te), Ti = T
    assert (derived['kp'], derived['ti']) == pytest.approx((10.0 / (0.05 * 5.0), 10.0), rel=1e-12)
    for bad in ({'ti': 20.0}, {'tuning.rule': 'mdp'}):
        with pytest.raises(ConfigError, match='tuning.rule'):
            make({**values, **bad})

    # steady state: model at rest with u = 2, y = r = 1 → prediction = y, e = 0, u stays 2
    values['b'] = 0.5
    ctrl = make(values)
    y, r, d = np.array([1.0]), np.array([1.0]), np.array([])
    ctrl.reset(y, np.array([2.0]))
    assert [ctrl.step(0.5 * k, y, r, d)[0] for k in range(3)] == pytest.approx([2.0] * 3, abs=1e-12)
    # primary gain change: in place (same object, model history kept), no jump although a
    # recomputation would move u by Δkp·(b·r − y) = −20·(−0.5) = 10
    values.update({'tuning.rule': 'none', 'kp': 20.0})
    same, u = change(ctrl, values, {'tuning.rule', 'kp'}, 1.5, y, r, d)
    assert same is ctrl and u[0] == pytest.approx(2.0, abs=1e-12)
    # model change: rebuilt, output continuous at that sample
    values['smith.dead_time'] = 3.6
    new, u = change(ctrl, values, {'smith.dead_time'}, 2.0, y, r, d)
    assert new is not ctrl and new.model.dead_time == 3.6 and u[0] == pytest.approx(2.0, abs=1e-12)
    # the new kp acts: a measurement step of 0.1 moves u by −kp·0.1 (prediction unchanged so far)
    assert new.step(2.5, np.array([1.1]), r, d)[0] == pytest.approx(2.0 - 20.0 * 0.1, abs=1e-9)


def test_every_kind_resolves_its_defaults_and_names_every_parameter_once():
    for name, kind in registry.KINDS.items():
        names = [s.name for s in node_specs.controller_specs(name)]
        assert len(names) == len(set(names)), name
        settings = resolve(kind, {})
        assert set(settings.values) == {s.name for s in kind.specs()}
        assert make({'controller': name}) is not None


def test_every_kind_module_is_in_the_table_and_an_error_in_one_surfaces():
    """A kind is a module of core/control/kinds plus its table line: the table lists every such
    module (imported at the top of the registry, so an error inside one fails loudly instead of
    making the kind vanish from the choices)."""
    import pkgutil

    import tank_control.core.control.kinds as package
    helpers = {'base', 'groups', 'guard', 'registry'}       # what kinds share, and the table
    modules = {m.name for m in pkgutil.iter_modules(package.__path__)} - helpers
    assert modules == {name for name in registry.BUILT_IN}
