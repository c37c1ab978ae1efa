"""core/loop.py: tick arithmetic, ZOH, controller instants, noise, trace columns and CSV."""
from __future__ import annotations

import numpy as np
import pytest

from tank_control.core.loop import run_loop
from tank_control.core.reference import reference_from_params
from tank_control.core.trace import Trace


class Integrator:
    """y' = k1·(u + v) with exact ZOH (the IPDT of [Viteckova] eq. 1 without dead time)."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ('v',)

    def __init__(self, k1: float) -> None:
        self.k1, self.y = k1, 0.0
        self.inputs: list[tuple[float, float, float]] = []

    def reset(self) -> None:
        self.y = 0.0

    def outputs(self) -> np.ndarray:
        return np.array([self.y])

    def step(self, u, d, dt) -> None:
        self.inputs.append((float(u[0]), float(d[0]), dt))
        self.y += self.k1 * dt * (u[0] + d[0])

    status: dict = {}


class PController:
    output_names, input_names, disturbance_names = ('y',), ('u',), ()

    def __init__(self, kp: float, sample_time: float) -> None:
        self.kp, self.sample_time, self.calls = kp, sample_time, []

    def reset(self, y, u) -> None:
        pass

    def step(self, t, y, r, d):
        self.calls.append(t)
        return np.array([self.kp * (r[0] - y[0])])

    status: dict = {}


def reference(**extra):
    return reference_from_params({'setpoint.channels': ['y'], 'setpoint.y.value': 1.0,
                                  'disturbance.channels': ['v'], 'disturbance.v.value': 0.0,
                                  **extra})


def test_p_control_of_an_integrator_follows_the_closed_form():
    k1, kp, ts = 0.5, 0.8, 0.1
    trace = run_loop(Integrator(k1), PController(kp, ts), reference(),
                     sample_time=ts, duration=2.0)
    # e[k+1] = (1 - k1·ts·kp)·e[k], e[0] = 1  (discrete ZOH loop, independent of the code)
    k = np.arange(len(trace))
    assert len(trace) == 21
    np.testing.assert_allclose(trace['t'], k * ts, rtol=0, atol=1e-15)
    np.testing.assert_allclose(1.0 - trace['y.y'], (1 - k1 * ts * kp) ** k, rtol=1e-12)
    np.testing.assert_allclose(trace['u.u'], kp * (1 - k1 * ts * kp) ** k, rtol=1e-12)
    assert trace.names == ('t', 'y.y', 'r.y', 'u.u', 'd.v')


def test_controller_runs_only_at_its_instants_and_holds_in_between():
    plant, ctrl = Integrator(1.0), PController(1.0, 0.3)
    trace = run_loop(plant, ctrl, reference(), sample_time=0.1, duration=1.0)
    assert ctrl.calls == pytest.approx([0.0, 0.3, 0.6, 0.9], abs=1e-15)
    u = trace['u.u']
    assert u[0] == u[1] == u[2] and u[3] == u[4] == u[5]
    # ZOH: the plant got the held input over every tick of length 0.1 s
    assert [dt for _, _, dt in plant.inputs] == [0.1] * 11


def test_disturbance_reaches_the_plant_with_the_tick_of_its_time():
    plant = Integrator(1.0)
    ref = reference_from_params({'setpoint.channels': ['y'], 'setpoint.y.value': 0.0,
                                 'disturbance.channels': ['v'],
                                 'disturbance.v.times': [0.0, 0.5],
                                 'disturbance.v.values': [0.0, 2.0]})
    trace = run_loop(plant, PController(0.0, 0.1), ref, sample_time=0.1, duration=1.0)
    assert [v for _, v, _ in plant.inputs][:7] == [0, 0, 0, 0, 0, 2, 2]
    assert trace['y.y'][6] == pytest.approx(0.2) and trace['d.v'][5] == 2.0


def test_noise_is_added_to_the_measurement_not_to_the_plant_state():
    draws = iter(np.arange(1, 100, dtype=float))
    plant = Integrator(1.0)
    trace = run_loop(plant, PController(0.0, 0.1), reference(), sample_time=0.1,
                     duration=0.5, noise=lambda: np.array([next(draws)]))
    assert trace['y.y'].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert plant.y == 0.0


def test_bad_wiring_and_sample_times_are_rejected():
    with pytest.raises(ValueError, match='integer multiple'):
        run_loop(Integrator(1.0), PController(1.0, 0.25), reference(), sample_time=0.1,
                 duration=1.0)
    ref = reference_from_params({'setpoint.channels': ['h'], 'setpoint.h.value': 1.0})
    with pytest.raises(ValueError, match="setpoint 'y'"):
        run_loop(Integrator(1.0), PController(1.0, 0.1), ref, sample_time=0.1, duration=1.0)


def test_trace_csv_round_trip_is_exact(tmp_path):
    trace = run_loop(Integrator(0.3), PController(0.7, 0.1), reference(), sample_time=0.1,
                     duration=1.0)
    again = Trace.read_csv(trace.write_csv(tmp_path / 'trace.csv'))
    assert again.names == trace.names
    assert max(trace.max_abs_difference(again).values()) == 0.0
