"""``run_loop(..., guards=...)``: the in-process loop refuses implausible values as the nodes do
(``range.*``, core/ranges.py): a corrupted measurement is held over and the loop recovers, an
implausible controller output never reaches the plant, an implausible setpoint is ignored."""
from __future__ import annotations

import numpy as np
import pytest

from tank_control.core import scenario
from tank_control.core.loop import Guards, run_loop
from tank_control.core.ranges import Ranges

IPDT_PID = 'config/ipdt_pid.yaml'


class Corrupted:
    """A plant whose measurement is ``value`` at the ticks in ``at`` (a bad sensor sample)."""

    def __init__(self, plant, at: set[int], value: float) -> None:
        self._plant, self._at, self._value, self._k = plant, at, value, 0
        self.output_names = plant.output_names
        self.input_names = plant.input_names
        self.disturbance_names = plant.disturbance_names
        self.status = {}
        self.nominal_inputs = getattr(plant, 'nominal_inputs', None)
        self.nominal_disturbances = getattr(plant, 'nominal_disturbances', None)

    def outputs(self):
        y = self._plant.outputs()
        return np.full_like(y, self._value) if self._k in self._at else y

    def step(self, u, d, dt):
        self._plant.step(u, d, dt)
        self._k += 1

    def reset(self):
        self._plant.reset()


def run(guarded: bool, corrupt: set[int], value: float = 1e300, duration: float = 600.0):
    built = scenario.build(scenario.sections_of(IPDT_PID))
    plant = Corrupted(built.plant, corrupt, value)
    return run_loop(plant, built.controller, built.reference, sample_time=built.sample_time,
                    duration=duration, guards=built.guards() if guarded else None)


def test_a_corrupted_sample_is_held_over_and_the_loop_recovers():
    clean = run(True, set())
    k = 1000                       # t = 100 s, while the loop is settling
    hit = run(True, {k})
    u, u_clean = hit['u.u'], clean['u.u']
    assert np.all(np.isfinite(u))
    assert u[k] == u[k - 1]                                    # the output held
    np.testing.assert_array_equal(u[:k], u_clean[:k])
    # after it the loop is back on the clean trajectory (one sample held: a tiny difference)
    assert np.max(np.abs(hit['y.y'] - clean['y.y'])[k + 1:]) < 0.05
    assert abs(hit['y.y'][-1] - clean['y.y'][-1]) < 1e-3
    # without the guards (what main did) the same sample wrecks the loop for good
    unguarded = run(False, {k})
    assert abs(unguarded['y.y'][-1] - clean['y.y'][-1]) > 1.0


def test_guards_do_not_change_a_clean_run():
    guarded, plain = run(True, set()), run(False, set())
    assert guarded.names == plain.names
    for name in plain.names:
        np.testing.assert_array_equal(guarded[name], plain[name])


class Wild:
    """A controller that outputs ``value`` at its ``bad``-th sample, else 1."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    sample_time = 0.1
    status: dict = {}

    def __init__(self, bad: int, value: float) -> None:
        self.bad, self.value, self.k = bad, value, 0
        self.resets: list = []

    def reset(self, y, u):
        self.resets.append((y.tolist(), u.tolist()))

    def step(self, t, y, r, d):
        self.k += 1
        return np.array([self.value if self.k - 1 == self.bad else 1.0])


@pytest.mark.parametrize('value', [-1e308, np.nan])
def test_an_implausible_controller_output_never_reaches_the_plant(value):
    built = scenario.build(scenario.sections_of(IPDT_PID))
    guards = Guards(controller=built.controller_setup.ranges, plant=built.plant_setup.ranges,
                    fail_safe_output=(0.0,))
    ctrl = Wild(bad=5, value=value)
    trace = run_loop(built.plant, ctrl, built.reference, sample_time=0.1, duration=10.0,
                     guards=guards)
    # -1e308 passes the controller (finite) and plant_node refuses it: u = 1 kept; NaN is the
    # controller's fault: the last output (1) held, as controller_node does. Either way the
    # IPDT (k1 = 0.05, To = 5 s) integrates u = 1 from t = 5 s: y = 0.05·(t − 5)
    t = trace.t
    np.testing.assert_allclose(trace['y.y'], 0.05 * np.maximum(t - 5.0, 0.0), atol=1e-12)
    # the trace shows what the controller sent: -1e308 as sent, NaN replaced by the held 1
    assert trace['u.u'][5] == (-1e308 if value == -1e308 else 1.0)


def test_an_implausible_setpoint_keeps_the_last_good_one():
    built = scenario.build(scenario.sections_of(IPDT_PID))
    guards = Guards(controller=Ranges({'y': (-10.0, 10.0)}), fail_safe_output=(0.0,))
    plain = run_loop(built.plant, built.controller, built.reference, sample_time=0.1,
                     duration=20.0, guards=guards)
    built = scenario.build(scenario.sections_of(IPDT_PID))
    narrow = Guards(controller=Ranges({'y': (-10.0, 0.5)}), fail_safe_output=(0.0,))
    held = run_loop(built.plant, built.controller, built.reference, sample_time=0.1,
                    duration=20.0, guards=narrow)
    # the setpoint step of ipdt_pid (to 1) is outside [-10, 0.5]: the controller keeps r = 0
    assert held['r.y'].max() == plain['r.y'].max() > 0.5      # the trace shows what was sent
    assert np.all(held['u.u'] == held['u.u'][0])              # y = r = 0 throughout: u constant
    assert not np.all(plain['u.u'] == plain['u.u'][0])


FOPDT_AUTOTUNE = 'config/fopdt_autotune.yaml'


@pytest.mark.parametrize('value', [1e6, -5000.0, 12000.0])
def test_an_input_far_outside_the_controllers_limits_is_refused_by_the_plant(value):
    """The plant's default range.u is the controller's output limits (here
    u_min 0, u_max 10000) widened by ranges.ACTUATOR_MARGIN (10 % of the span each side):
    [-1000, 11000]. An injected u outside (1e6 drove the IPDT to y ≈ 5000) is refused and the
    plant keeps the last good input."""
    built = scenario.build(scenario.sections_of(FOPDT_AUTOTUNE))
    assert built.plant_setup.ranges.bounds['u'] == (-1000.0, 11000.0)
    guards = Guards(controller=built.controller_setup.ranges, plant=built.plant_setup.ranges,
                    fail_safe_output=(0.0,))
    trace = run_loop(built.plant, Wild(bad=5, value=value), built.reference, sample_time=0.1,
                     duration=60.0, guards=guards)
    # u = 1 throughout as the plant takes it: y of the FOPDT (K 0.05, T 10 s, L 3 s) to u = 1
    t = trace.t
    expected = 0.05 * (1.0 - np.exp(-np.maximum(t - 3.0, 0.0) / 10.0))
    np.testing.assert_allclose(trace['y.y'], expected, atol=1e-9)
    # within the widened limits a hand-set value is taken
    inside = scenario.build(scenario.sections_of(FOPDT_AUTOTUNE))
    assert inside.plant_setup.ranges.accepts('u', 10500.0)
    assert inside.plant_setup.ranges.accepts('u', -500.0)
