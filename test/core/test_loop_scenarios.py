"""``run_loop`` on every shipped scenario equals a plain transcription of the lockstep arithmetic
(core/loop.py's docstring): per tick new arrays, channels matched by name in dicts, the setpoints
read every tick. Both drive freshly built objects of the scenario, so the bookkeeping of the
in-process loop (arrays only made when values change, held schedules, table building) is what
is compared, bit for bit."""
from __future__ import annotations

import math

import numpy as np
import pytest
from support import CONFIG, SCENARIOS

from tank_control.core import scenario
from tank_control.core.interfaces import to_ns
from tank_control.core.loop import warm_start

FILES = sorted(CONFIG.glob('*.yaml')) + sorted(SCENARIOS.glob('*.yaml'))
MAX_DURATION = 2200.0
"""[s] of simulated time per scenario at most (the tanks' first setpoint changes are within)."""


def plain_loop(built: scenario.Built, duration: float) -> dict[str, list[float]]:
    plant, controller, reference = built.plant, built.controller, built.reference
    ts = built.sample_time
    ts_ns, cts_ns = to_ns(ts), to_ns(controller.sample_time)
    u = dict(zip(plant.input_names, np.asarray(plant.nominal_inputs(), dtype=float).tolist()))
    d = dict(zip(plant.disturbance_names,
                 np.asarray(plant.nominal_disturbances(), dtype=float).tolist()))
    columns: dict[str, list[float]] = {'t': []}
    u_ctrl = np.array([u[n] for n in controller.input_names])
    started = False
    for k in range(to_ns(duration) // ts_ns + 1):
        t = k * ts_ns / 1e9
        r_all = dict(zip(reference.setpoint_names, reference.setpoints(t).tolist()))
        d_ref = dict(zip(reference.disturbance_names, reference.disturbances(t).tolist()))
        d.update(d_ref)
        y_all = dict(zip(plant.output_names, (plant.outputs() + built.noise.sample()).tolist()))
        if (k * ts_ns) % cts_ns == 0:
            y_c = np.array([y_all[n] for n in controller.output_names])
            if not started and all(math.isfinite(v) for v in y_c):
                warm_start(controller, y_c)
                started = True
            u_ctrl = np.asarray(controller.step(
                t, y_c, np.array([r_all[n] for n in controller.output_names]),
                np.array([d[n] for n in controller.disturbance_names])), dtype=float)
            u.update(zip(controller.input_names, u_ctrl.tolist()))
        row = {'t': t, **{f'y.{n}': v for n, v in y_all.items()},
               **{f'r.{n}': v for n, v in r_all.items()},
               **{f'u.{n}': v for n, v in zip(controller.input_names, u_ctrl.tolist())},
               **{f'd.{n}': v for n, v in d_ref.items()}}
        for name, value in row.items():
            columns.setdefault(name, []).append(value)
        plant.step(np.array([u[n] for n in plant.input_names]),
                   np.array([d[n] for n in plant.disturbance_names]), ts)
    return columns


@pytest.mark.parametrize('path', FILES, ids=[f.name for f in FILES])
def test_run_loop_equals_the_plain_loop_on_every_shipped_scenario(path):
    sections = scenario.sections_of(path)
    duration = min(scenario.duration_of(sections, None), MAX_DURATION)
    trace = scenario.run(scenario.build(sections), duration)
    plain = plain_loop(scenario.build(sections), duration)
    assert list(trace.names) == list(plain)
    for name, values in plain.items():
        np.testing.assert_array_equal(trace[name], np.array(values), err_msg=name)
