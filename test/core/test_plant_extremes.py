"""Every plant kind keeps finite states and outputs whatever finite inputs it is stepped with.

Each input and disturbance channel of every plant kind (default parameters) is held at an
extreme finite value (±1e308, ±1e300, ±1e154, ±1e12, ±5e-324, 0) for a run of short steps and
one long step; outputs and numeric status must stay finite, and a good input afterwards must
give finite outputs again. Run as a script it prints the counts:
``python test/core/test_plant_extremes.py``.
"""
from __future__ import annotations

import math
import sys
from collections.abc import Iterator

import numpy as np
import pytest

from tank_control.core.loop import nominal_disturbances, nominal_inputs
from tank_control.core.plants.kinds import registry

EXTREMES = (1e308, -1e308, 1e300, -1e300, 1e154, -1e154, 1e12, -1e12, 5e-324, -5e-324, 0.0)
STEPS = ((0.1, 20), (1.0, 20), (600.0, 2))
"""(dt [s], number of steps) the extreme value is held for."""


def cases() -> Iterator[tuple[str, str, float, float, int]]:
    for kind, plant_kind in registry.KINDS.items():
        model = plant_kind.build
        for channel in (*model.input_names, *model.disturbance_names):
            for value in EXTREMES:
                for dt, n in STEPS:
                    yield kind, channel, value, dt, n


def broken(kind: str, channel: str, value: float, dt: float, n: int) -> str | None:
    """What went wrong holding ``channel`` at ``value`` for ``n`` steps of ``dt``, else None."""
    plant = registry.make_plant(kind)
    u = nominal_inputs(plant)
    d = nominal_disturbances(plant)
    (u if channel in u else d)[channel] = value
    for k in range(n):
        try:
            plant.step(np.array(list(u.values())), np.array(list(d.values())), dt)
        except (ArithmeticError, OverflowError) as exc:
            return f'{type(exc).__name__}: {exc} at step {k}'
        except ValueError as exc:
            return f'refused a finite input: {exc}'
        y = plant.outputs()
        if not np.all(np.isfinite(y)):
            return f'y = {y.tolist()} at step {k}'
        bad = {key: v for key, v in plant.status.items()
               if isinstance(v, float) and not math.isfinite(v)}
        if bad:
            return f'status {bad} at step {k}'
    good_u, good_d = nominal_inputs(plant), nominal_disturbances(plant)
    plant.step(np.array(list(good_u.values())), np.array(list(good_d.values())), 1.0)
    if not np.all(np.isfinite(plant.outputs())):
        return f'y = {plant.outputs().tolist()} after a good input'
    return None


@pytest.mark.parametrize('kind', sorted(registry.KINDS))
def test_extreme_inputs_keep_the_plant_finite(kind):
    failures = []
    for case in cases():
        if case[0] == kind:
            reason = broken(*case)
            if reason:
                failures.append(f'{case[1]} = {case[2]:g}, dt {case[3]:g} x {case[4]}: {reason}')
    assert failures == [], '\n'.join(failures)


def test_non_finite_inputs_are_still_refused():
    for kind in registry.KINDS:
        plant = registry.make_plant(kind)
        u = np.array(list(nominal_inputs(plant).values()))
        d = np.array(list(nominal_disturbances(plant).values()))
        u[0] = math.nan
        with pytest.raises(ValueError):
            plant.step(u, d, 0.1)


if __name__ == '__main__':
    all_cases = list(cases())
    failed = [(case, reason) for case in all_cases if (reason := broken(*case))]
    print(f'plant cases {len(all_cases)}, broken {len(failed)}')
    for case, reason in failed:
        print(f'  {case[0]} {case[1]} = {case[2]:g}, dt {case[3]:g} x {case[4]}: {reason}')
    sys.exit(1 if failed else 0)
