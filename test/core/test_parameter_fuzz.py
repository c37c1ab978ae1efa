"""Property-based fuzz of every controller and plant kind's declared parameters (hypothesis).

For every kind in the registries (with a partner kind to close the loop: ``support/param_fuzz``)
one to three of its node's parameters get hostile values — denormals, underflows such as
1e-170 for two times whose product underflows, huge and negative values, nan/inf, integers
beyond int64, values of the wrong type — given at start-up (a params file) or as a live
``ros2 param set``. Each value is refused with a one-line reason by the validation the node
runs, or the in-process loop with it stays alive (no exception, no frozen step) and finite for
200 samples. The values that once ended the nodes are always tried (``@example``).

A value that makes the controller contradict itself is refused: a Smith predictor whose loop is
unstable on its own model (``smith.gain -1`` with kp 2, an ``@example`` that must be refused). An
accepted value whose loop diverges geometrically (``param_fuzz.diverged``: the tracking error
grows 1000-fold over the run) is counted and listed, not failed, when the divergence comes from
the plant differing from the controller's model (e.g. an FSA, which places its poles exactly on
its model, given fsa.gain 0.001 for a plant of gain 0.05): no node can know the plant its model
is wrong for; the outputs stay within the controller's limits and the plants clip their states.

Budget: the profile ``HYPOTHESIS_PROFILE`` (default ``ci``: 400 changes per test, about 15 s
in ``make test``; ``long``: 5 000 per test; both derandomised, so a run is reproducible)::

    HYPOTHESIS_PROFILE=long .venv/bin/python -m pytest -q -n 0 -p no:cacheprovider \
        test/core/test_parameter_fuzz.py -s

``-s`` prints the counts (changes and values tried, refused, accepted, diverging) per test.
"""
from __future__ import annotations

import os
from collections import Counter

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from support import param_fuzz

_COMMON = {'deadline': None, 'derandomize': True, 'database': None, 'print_blob': True,
           'suppress_health_check': [HealthCheck.too_slow, HealthCheck.filter_too_much,
                                     HealthCheck.data_too_large]}
settings.register_profile('ci', max_examples=400, **_COMMON)
settings.register_profile('long', max_examples=5000, **_COMMON)
settings.register_profile('dev', max_examples=int(os.environ.get('FUZZ_EXAMPLES', '1000')),
                          **_COMMON)
PROFILE = os.environ.get('HYPOTHESIS_PROFILE', 'ci')
settings.load_profile(PROFILE)

COUNTS: dict[str, Counter] = {}
DIVERGING: list[str] = []


def _case(node: str) -> st.SearchStrategy:
    targets = [t for t in param_fuzz.targets() if t.node == node]
    return st.tuples(st.sampled_from(targets), st.sampled_from(('file', 'live'))).flatmap(
        lambda th: st.tuples(st.just(th[0]), st.just(th[1]),
                             param_fuzz.change_strategy(th[0])))


def _check(node: str, case: tuple) -> None:
    if isinstance(case[0], str):          # an @example: (node, source or kind, how, changes)
        case = (_target(case[0], case[1]), case[2], case[3])
    target, how, changes = case
    verdict = param_fuzz.verdict(target, changes, how)
    counts = COUNTS.setdefault(node, Counter())
    counts['tried'] += 1
    counts['values'] += len(changes)
    counts[how] += 1
    counts['refused' if verdict.refused else 'accepted'] += 1
    if verdict.diverging and not verdict.broken:
        counts['diverging'] += 1
        DIVERGING.append(f'{how} {node} {target.kind} ({target.source}) {changes!r}: '
                         f'{verdict.diverging}')
    counts['broken'] += verdict.broken is not None
    assert verdict.broken is None, (
        f'{how} {node} {target.kind} {changes!r}: {verdict.broken}')


def test_a_smith_predictor_unstable_on_its_own_model_is_refused_live_and_at_start_up():
    target = _target('controller', 'smith_pi')
    for how in ('live', 'file'):
        verdict = param_fuzz.verdict(target, {'smith.gain': -1.0, 'kp': 2.0}, how)
        assert verdict.refused and 'Smith loop would be unstable' in verdict.reason, verdict


def _target(node: str, source: str) -> param_fuzz.Target:
    return next(t for t in param_fuzz.targets()
                if t.node == node and (t.source == source or t.kind == source))


# values that once crashed the nodes (always tried, before the drawn ones)
@example(('controller', 'ipdt_pid.yaml', 'live', {'tuning.dead_time': 5e-324}))
@example(('controller', 'ipdt_pid.yaml', 'file', {'tuning.dead_time': 5e-324}))
@example(('controller', 'pid', 'file', {'ti': 1e-170, 'td': 1e-170}))
@example(('controller', 'pid', 'live', {'ti': 1e-170, 'td': 1e-170}))
@given(_case('controller'))
def test_every_controller_parameter_value_is_refused_or_runs(case):
    _check('controller', case)


@example(('plant', 'ipdt_pid.yaml', 'live', {'real_time_factor': 1e-12}))
@example(('plant', 'ipdt_pid.yaml', 'live', {'real_time_factor': 5e-324}))
@example(('plant', 'ipdt_pid.yaml', 'file', {'real_time_factor': 1e-300}))
@example(('plant', 'foupdt', 'file', {'time_constant': 1e-06}))   # found by the long run
@example(('plant', 'tank_two_loop.yaml', 'live', {'integration_step': 1e-06}))   # and this
@example(('plant', 'transfer_function', 'file',        # a denormal leading coefficient
          {'sample_time': 0.001, 'den': [2.225073858507203e-309, 0.0]}))
@given(_case('plant'))
def test_every_plant_parameter_value_is_refused_or_runs(case):
    _check('plant', case)


def teardown_module() -> None:
    for node, counts in COUNTS.items():
        print(f'\nparameter fuzz ({PROFILE}) {node}: tried {counts["tried"]} changes '
              f'({counts["values"]} parameter values; {counts["file"]} at start-up, '
              f'{counts["live"]} live), refused {counts["refused"]}, accepted '
              f'{counts["accepted"]} (of which diverging {counts["diverging"]}), broken '
              f'{counts["broken"]}')
    for line in DIVERGING:
        print('  accepted, diverging: ' + line)
