"""The kind contract (``tank_control.testing``, issue 32 §4) on every built-in kind: the same
kit users run on theirs. Replaces the per-kind copies of these checks (manual/auto, live
changes of plants, read-only refusals). The kit's failures name the property with numbers."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest

from tank_control.core.analysis.linear import RationalModel
from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind, channels
from tank_control.core.params import param
from tank_control.core.plants.kinds import registry as plants
from tank_control.testing import ContractError, check_controller_kind, check_plant_kind

LIMITS = {'u_min': -1.0, 'u_max': 1.0}
TANK = {'y0': [81.0, 33.57], 'r0': [81.0, 33.57]}
CONTROLLERS = {
    'pid': ({**LIMITS, 'ti': 5.0, 'td': 1.0}, {}),
    'relay_autotune': ({**LIMITS, 'ti': 5.0, 'td': 0.5}, {}),
    'lead_lag': ({**LIMITS, 'lead_lag.ti': 5.0, 'lead_lag.td': 1.0}, {}),
    'smith_pi': ({**LIMITS, 'ti': 5.0}, {}),
    'fsa': (LIMITS, {}),
    'two_loop_pi': ({}, TANK),
    # an optimiser: a weight change moves the optimal move (not claimed bumpless)
    'mpcs': ({}, {**TANK, 'changes': {}}),
}
PLANTS = {'mixing_tank': {'u': 14.0}, 'mixing_tank_linear': {'u': 14.0}}


def test_every_built_in_kind_is_checked():
    assert set(CONTROLLERS) == set(registry.BUILT_IN)


@pytest.mark.parametrize('name', sorted(CONTROLLERS))
def test_every_built_in_controller_kind_meets_the_contract(name):
    values, options = CONTROLLERS[name]
    report = check_controller_kind(name, values, **options)
    for prop in ('determinism', 'reset', 'bad parameter values refused',
                 'refused change leaves the controller untouched'):
        assert prop in report.checked
    assert 'output limits and anti-windup' in report.checked
    if name not in ('two_loop_pi', 'mpcs'):          # the SISO kinds have a mode
        assert 'manual/auto' in report.checked


@pytest.mark.parametrize('name', sorted(plants.BUILT_IN))
def test_every_built_in_plant_kind_meets_the_contract(name):
    report = check_plant_kind(name, **PLANTS.get(name, {}))
    assert {'determinism', 'reset', 'bad parameter values refused', 'live changes'} <= set(
        report.checked)
    if plants.BUILT_IN[name].linear is not None:
        assert 'linear description' in report.checked   # the model is the simulated plant


# -------------------------------------------------- the kit says what broke, with numbers
def test_a_pi_without_anti_windup_is_caught_with_its_numbers():
    with pytest.raises(ContractError) as info:
        check_controller_kind('pid', {**LIMITS, 'ti': 5.0, 'anti_windup': 'none'})
    message = str(info.value)
    assert message.startswith('pid: anti-windup: after 2000 samples at the limit [1.0]')
    assert 'error 100' in message


class _Leaky:
    """A P controller whose reset forgets the output, and whose copy shares its state."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    sample_time = 0.1
    status: dict = {}

    def __init__(self, gain):
        self.gain, self.state = gain, [0.0]

    def reset(self, y, u):
        pass

    def step(self, t, y, r, d):
        self.state[0] += 1e-3
        return np.array([min(max(self.gain * (r[0] - y[0]) + self.state[0], -1.0), 1.0)])


@dataclass(frozen=True)
class _LeakyConfig:
    gain: float = param(1.0, 'gain', unit='-', min=0.0, max=10.0)


LEAKY = ControllerKind(name='leaky', description='broken on purpose', config=_LeakyConfig,
                       groups=(channels(('y',), ('u',)),),
                       build=lambda s: _Leaky(s.config.gain),
                       input_limits=lambda s: {'u': (-1.0, 1.0)})


def test_a_controller_that_ignores_reset_is_caught(monkeypatch):
    with pytest.raises(ContractError, match=r'^leaky: reset: after reset\(y=.*\) the next '
                                            r'output is \[.*\] \(differs by'):
        check_controller_kind(LEAKY)


def test_a_plant_whose_linear_model_is_wrong_is_caught():
    fopdt = plants.BUILT_IN['fopdt']
    wrong = replace(fopdt, linear=lambda c: RationalModel((c.gain,), (c.time_constant, 1.0),
                                                          c.dead_time + 0.5))
    with pytest.raises(ContractError, match=r'^fopdt: linear description: the model .* gives '
                                            r'G\(z\) = .* the simulated plant'):
        check_plant_kind(wrong)
