"""A costly tuning rule's design done off the sampling path (nodes/live_derive.py, as
controller_node does in wall mode): decided by the rule, checked on acceptance without the
design, and the worker's gains are exactly the ones the synchronous derivation sets (lockstep,
sim, in-process), or the reason the design is refused."""
from __future__ import annotations

import pytest

from tank_control.core.control.kinds import registry
from tank_control.core.scenario import controller_setup
from tank_control.core.tuning import rules
from tank_control.nodes import live_derive

WAIT = 60.0
VALUES = {'controller': 'pid', 'sample_time': 0.5, 'tuning.rule': 'ms', 'tuning.gain': 1.3,
          'tuning.dead_time': 0.5, 'tuning.time_constant': 2.0, 'robustness.ms_max': 1.6}
GAINS = ('kp', 'ti', 'td', 'b', 'c')


def _derive(changes: dict, changed: frozenset[str]) -> live_derive.LiveDerive:
    kind = registry.get_kind('pid')
    names = frozenset(controller_setup(VALUES).settings.values)
    values = {**controller_setup(VALUES).settings.values, 'controller': 'pid', **changes}
    old = {n: controller_setup(VALUES).settings.values[n] for n in changed}
    job = live_derive.LiveDerive(kind, names, values, changed, old)
    assert job.wait(WAIT)
    return job


def test_the_rule_decides_what_is_designed_off_the_sampling_path():
    ms, simc = {'tuning.rule': 'ms'}, {'tuning.rule': 'simc'}
    assert live_derive.costly(ms, frozenset({'tuning.ms_target'}))
    assert live_derive.costly(ms, frozenset({'tuning.gain', 'u_max'}))
    assert live_derive.costly(ms, frozenset({'n'}))           # the implemented loop's filter
    assert not live_derive.costly(ms, frozenset({'u_max', 'kp'}))
    assert not live_derive.costly(simc, frozenset({'tuning.tau_c'}))   # a closed form
    assert 'ms' in rules.COSTLY_RULES and 'simc' not in rules.COSTLY_RULES


def test_the_worker_derives_exactly_the_synchronous_gains():
    rules._ms_design.cache_clear()
    job = _derive({'tuning.ms_target': 1.5}, frozenset({'tuning.ms_target'}))
    expected = controller_setup({**VALUES, 'tuning.ms_target': 1.5},
                                given={'tuning.ms_target'}).settings.values
    assert job.gains() == {k: expected[k] for k in GAINS}     # bit for bit
    assert job.old == {'tuning.ms_target': 1.4}


def test_a_design_the_guard_refuses_is_checked_on_acceptance_only_without_it():
    values = {**VALUES, 'tuning.ms_target': 2.0}
    # accepted without the design (the running gains on the same model) ...
    controller_setup(live_derive.without_design(values), given={'tuning.ms_target'})
    # ... refused by the worker, with the synchronous check's reason
    job = _derive({'tuning.ms_target': 2.0}, frozenset({'tuning.ms_target'}))
    with pytest.raises(ValueError, match=r'Ms would be 2 > robustness.ms_max 1.6'):
        job.gains()
