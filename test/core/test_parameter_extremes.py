"""No parameter value a controller accepts can make its output non-finite.

A sweep over every declared parameter of every controller kind with hostile values (0, ±5e-324,
±1e-300, ±1e300, ±1e308, -1, huge integers, one- and two-item lists of those, every choice):
each value is tried as a start-up value (``controller_setup`` as controller_node and the
in-process loop validate it) and, where the parameter is not read-only, as a live change as
controller_node checks and applies it (``registry.prepare_change`` builds the candidate and tries
it from the last sample; the checked candidate takes over at the next sample). Every accepted set must leave the outputs finite over the next samples.
Run as a script it prints the counts: ``python test/core/test_parameter_extremes.py``.
"""
from __future__ import annotations

import pytest

import copy
import math
import sys
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core import node_specs
from tank_control.core.control.kinds import registry
from tank_control.core.params import ConfigError, ParamSpec
from tank_control.core.plants.mixing_tank import OPERATING_POINT as OP
from tank_control.core.scenario import controller_setup

TINY, HUGE = 5e-324, 1e308
FLOATS = (0.0, TINY, -TINY, 1e-300, -1e-300, 1e-160, 1e154, -1e154, 1e300, -1e300, HUGE, -HUGE,
          -1.0)
INTS = (0, -1, 2 ** 62, -(2 ** 62), 10 ** 9)
STEPS_BEFORE, STEPS_AFTER = 5, 25

#: the signals the sweep samples each kind with: the mixing tank's operating point for the
#: kinds that control it, a unit step for the SISO kinds
TANK_Y, TANK_R = (OP.h, OP.T), (OP.h + 2.0, OP.T - 1.0)
TANK_D = (OP.F_D, OP.T_D)


def hostile_values(spec: ParamSpec) -> tuple[Any, ...]:
    """The hostile values tried for one parameter (by the type of its default)."""
    default = spec.default
    if isinstance(default, bool):
        return (not default,)
    if isinstance(default, str):
        return tuple(c for c in spec.choices or () if c != default)
    if isinstance(default, int):
        return INTS
    if isinstance(default, float):
        return FLOATS
    if isinstance(default, list) and default and isinstance(default[0], float):
        return tuple([x] for x in FLOATS) + tuple([x, x] for x in FLOATS)
    return ()


@dataclass
class Counts:
    tried: int = 0
    refused: int = 0
    accepted: int = 0
    broken: list = None

    def __post_init__(self) -> None:
        self.broken = []


def signals(controller: Any, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample ``k``'s measurement (a small oscillation about the operating point), setpoint and
    measured disturbance, by the controller's channels."""
    n_out = len(controller.output_names)
    y0, r = (TANK_Y, TANK_R) if n_out == 2 else ((0.0,), (1.0,))
    y = np.array(y0, dtype=float) + 0.1 * math.sin(0.3 * k)
    d = np.array(TANK_D[:len(controller.disturbance_names)], dtype=float)
    return y, np.array(r, dtype=float), d


def run_steps(controller: Any, k0: int, n: int) -> tuple[Any, str | None]:
    """``n`` samples from sample ``k0``; the first non-finite output, else None."""
    for k in range(k0, k0 + n):
        y, r, d = signals(controller, k)
        try:
            u = np.asarray(controller.step(k * controller.sample_time, y, r, d), dtype=float)
        except Exception as exc:       # noqa: BLE001 - any failure of an accepted set counts
            return controller, f'{type(exc).__name__}: {exc} at sample {k}'
        if not np.all(np.isfinite(u)):
            return controller, f'u = {u.tolist()} at sample {k}'
    return controller, None


def started(values: dict[str, Any]) -> Any:
    """The controller of ``values``, warm-started and run for a few samples."""
    controller = controller_setup(values).build_controller()
    y, _, _ = signals(controller, 0)
    u0 = getattr(controller, 'initial_output', None)
    if u0 is not None:
        controller.reset(y, np.asarray(u0, dtype=float))
    return controller


#: per kind: its controller with the default parameters after samples 0 .. STEPS_BEFORE - 2,
#: the state every live change starts from (built once; each change takes a deep copy, whose
#: outputs equal a fresh build's: building MPCS is most of the sweep's time otherwise)
_RUNNING: dict[str, Any] = {}


def running_before_change(kind: str) -> Any:
    """A copy of the kind's controller run up to the sample before the last one (see _RUNNING)."""
    if kind not in _RUNNING:
        controller, broken = run_steps(started({'controller': kind}), 0, STEPS_BEFORE - 1)
        assert broken is None, broken
        _RUNNING[kind] = controller
    return copy.deepcopy(_RUNNING[kind])


def try_startup(kind: str, spec: ParamSpec, value: Any) -> tuple[bool, str | None]:
    """(accepted, what broke) for ``value`` given at start-up."""
    values = {'controller': kind, spec.name: value}
    try:
        controller = started(values)
    except (ConfigError, ValueError):
        return False, None
    _, broken = run_steps(controller, 0, STEPS_BEFORE + STEPS_AFTER)
    return True, broken


def try_live(kind: str, spec: ParamSpec, value: Any) -> tuple[bool, str | None]:
    """(accepted, what broke) for ``value`` set on a running controller, checked and applied as
    controller_node does: the parameter's spec, its cross-check (``controller_setup``), the
    candidate built and tried from the last sample (``registry.prepare_change``); the checked
    candidate takes effect at the next sample."""
    base = {'controller': kind}
    controller = running_before_change(kind)                          # samples 0 .. last-1
    if spec.check(value) is not None:
        return False, None
    candidate = {**controller_setup(base).values(), spec.name: value}
    kind_ = registry.get_kind(kind)
    try:
        if kind_.derive is not None:
            names = {s.name for s in kind_.specs()}
            derived = kind_.derive({k: v for k, v in candidate.items() if k in names})
            candidate.update({k: v for k, v in derived.items() if k != spec.name})
        setup = controller_setup(candidate, given=frozenset({spec.name}))
    except ConfigError:
        return False, None
    last = STEPS_BEFORE - 1
    t_last = last * controller.sample_time
    y, r, d = signals(controller, last)
    u_last = np.asarray(controller.step(t_last, y, r, d), dtype=float)   # the last sample
    changed = frozenset({spec.name}) & {s.name for s in kind_.specs()}
    y_next, r_next, d_next = signals(controller, STEPS_BEFORE)
    t_next = STEPS_BEFORE * controller.sample_time
    prepare = getattr(registry, 'prepare_change', None)
    try:
        if prepare is None:            # a controller_node that applies changes unchecked
            controller, u = registry.step_with_changes(setup.kind, controller, setup.settings,
                                                       changed, t_next, y_next, r_next, d_next)
        else:
            try:
                prepared = prepare(setup.kind, controller, setup.settings, changed,
                                   trial=(t_last, y, r, d), u_last=u_last)
            except ValueError:
                return False, None     # refused with a reason before acceptance
            controller, u = prepared.take_effect(controller, t_next, y_next, r_next, d_next)
    except Exception as exc:           # noqa: BLE001 - the node would log 'could not be applied'
        return True, f'not applied: {type(exc).__name__}: {exc}'
    if not np.all(np.isfinite(u)):
        return True, f'u = {np.asarray(u).tolist()} at the change'
    _, broken = run_steps(controller, STEPS_BEFORE + 1, STEPS_AFTER)
    return True, broken


def cases() -> Iterator[tuple[str, str, ParamSpec, Any]]:
    for kind in registry.KINDS:
        for spec in node_specs.controller_specs(kind):
            if spec.name in ('controller',):
                continue
            for value in hostile_values(spec):
                yield 'start-up', kind, spec, value
                if not spec.read_only:
                    yield 'live', kind, spec, value


def sweep() -> tuple[Counts, Counter]:
    counts = Counts()
    per_kind: Counter = Counter()
    for how, kind, spec, value in cases():
        counts.tried += 1
        per_kind[kind] += 1
        accepted, broken = (try_startup if how == 'start-up' else try_live)(kind, spec, value)
        if not accepted:
            counts.refused += 1
            continue
        counts.accepted += 1
        if broken:
            counts.broken.append(f'{how} {kind} {spec.name} = {value!r}: {broken}')
    return counts, per_kind


@pytest.mark.slow
def test_no_accepted_parameter_makes_an_output_non_finite():
    counts, _ = sweep()
    assert counts.tried > 1000 and counts.refused > 0 and counts.accepted > 0
    assert counts.broken == [], '\n'.join(counts.broken)


if __name__ == '__main__':
    result, kinds = sweep()
    print(f'tried {result.tried}, refused {result.refused}, accepted {result.accepted}, '
          f'accepted-and-broken {len(result.broken)}  (per kind: {dict(kinds)})')
    for line in result.broken:
        print('  ' + line)
    sys.exit(1 if result.broken else 0)
