"""What the cheap per-sample paths of the core objects must keep: the same refusals of bad input
(float64 arrays, tuples and other forms alike), the same noise stream, settings that act at once
after a change, and schedules that really hold their value until ``held_until``."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.control.multiloop import TwoLoopPi, document_config
from tank_control.core.control.pid import Pid2Dof, PidConfig
from tank_control.core.plants.fopdt import Fopdt
from tank_control.core.plants.ipdt import Ipdt
from tank_control.core.plants.mixing_tank import MixingTank, MixingTankConfig
from tank_control.core.plants.noise import MeasurementNoise
from tank_control.core.reference import ChannelSchedule

NAN, INF = math.nan, math.inf


def forms(values: list[float]) -> list[object]:
    """The same vector as a float64 array, a tuple of floats, a list and a column array."""
    return [np.array(values, dtype=float), tuple(values), list(values),
            np.array(values, dtype=float).reshape(-1, 1)]


# ------------------------------------------------------------------------- plants refuse
@pytest.mark.parametrize('plant_type', [Ipdt, Fopdt])
@pytest.mark.parametrize('u, d, words', [
    ([NAN], [0.0], 'u: non-finite'),
    ([INF], [0.0], 'u: non-finite'),
    ([1.0, 2.0], [0.0], 'u: 2 values given, expected 1'),
    ([], [0.0], 'u: 0 values given, expected 1'),
    ([1.0], [-INF], 'd: non-finite'),
    ([1.0], [0.0, 0.0], 'd: 2 values given, expected 1'),
])
def test_siso_plants_refuse_bad_input_in_every_form(plant_type, u, d, words):
    for u_form, d_form in zip(forms(u), forms(d)):
        plant = plant_type()
        plant.step(np.array([1.0]), np.array([0.0]), 1.0)
        before = (plant.outputs().tolist(), dict(plant.status))
        with pytest.raises(ValueError, match=words):
            plant.step(u_form, d_form, 1.0)
        assert (plant.outputs().tolist(), dict(plant.status)) == before


@pytest.mark.parametrize('dt', [NAN, -0.1, INF, '0.1', np.array([0.1]), None])
def test_a_bad_step_length_is_refused_after_good_ones(dt):
    plant = Ipdt()
    for _ in range(3):
        plant.step(np.array([1.0]), np.array([0.0]), 0.1)   # the step length is remembered
    before = (plant.outputs().tolist(), dict(plant.status))
    with pytest.raises(ValueError, match='dt'):
        plant.step(np.array([1.0]), np.array([0.0]), dt)
    assert (plant.outputs().tolist(), dict(plant.status)) == before


def test_siso_plant_accepts_the_same_inputs_in_every_form():
    outputs = []
    for u_form, d_form in zip(forms([2.0]), forms([-0.5])):
        plant = Fopdt()
        for dt in (0.1, 0.1, 0.25, 1, np.float64(0.1)):
            plant.step(u_form, d_form, dt)
        outputs.append(plant.outputs().tolist())
    assert all(o == outputs[0] for o in outputs)
    # the exact response of K/(T s + 1) e^(-L s) to w = 1.5 from t = L = 3 s up to t = 1.55 s:
    # still inside the dead time, so y = 0
    assert outputs[0] == [0.0]


@pytest.mark.parametrize('u, d, words', [
    ([NAN, 37.0], [12.0, 33.0, 62.0, 23.0], 'u: non-finite'),
    ([14.0], [12.0, 33.0, 62.0, 23.0], 'u: 1 values given, expected 2'),
    ([14.0, 37.0], [12.0, 33.0, INF, 23.0], 'd: non-finite'),
    ([14.0, 37.0], [12.0, 33.0, 62.0], 'd: 3 values given, expected 4'),
])
def test_mixing_tank_refuses_bad_input_in_every_form(u, d, words):
    for u_form, d_form in zip(forms(u), forms(d)):
        plant = MixingTank()
        plant.step(np.array([14.0, 37.0]), np.array([]), 1.0)
        before = (plant.outputs().tolist(), dict(plant.status))
        with pytest.raises(ValueError, match=words):
            plant.step(u_form, d_form, 1.0)
        assert (plant.outputs().tolist(), dict(plant.status)) == before


def test_mixing_tank_clips_and_counts_out_of_range_inputs_one_by_one():
    plant = MixingTank()
    plant.step(np.array([-5.0, 37.0]), np.array([12.0, 33.0, 150.0, -1.0]), 1.0)
    status = plant.status
    assert (status['clipped_F_H'], status['clipped_F_Cin'], status['clipped_F_D']) == (1, 0, 0)
    assert (status['clipped_T_D'], status['clipped_T_H'], status['clipped_T_C']) == (0, 1, 1)
    assert status['clipped_flows'] == 1
    plant.step(np.array([14.0, 37.0]), np.array([12.0, 33.0, 62.0, 23.0]), 1.0)
    assert plant.status['clipped_flows'] == 1     # in range: nothing more counted


def test_mixing_tank_change_of_alpha_acts_on_the_next_step():
    """A live change takes effect at once (the constants kept from the configuration are
    renewed): the changed plant equals one built with the new value from the start."""
    changed, built = MixingTank(), MixingTank(MixingTankConfig(alpha=6.0))
    changed.configure(alpha=6.0)
    for _ in range(200):
        for plant in (changed, built):
            plant.step(np.array([14.0, 37.0]), np.array([12.0, 33.0, 62.0, 23.0]), 1.0)
    assert changed.outputs().tolist() == built.outputs().tolist()
    # less outflow at the same level: the tank fills (equilibrium h = (63/6)² = 110 cm)
    assert changed.outputs()[0] > MixingTankConfig().initial_h + 5.0


# ----------------------------------------------------------------------------- the PID
def test_pid_gain_change_before_the_first_sample_equals_a_pid_built_with_it():
    """The per-configuration constants (gain, derivative pole, rate step, Tt) follow
    ``set_gains``."""
    new = dict(kp=2.0, td=3.0, n=5.0, du_max=0.5, ti=20.0, tracking_time=7.0)
    changed = Pid2Dof(PidConfig(kp=1.0, ti=10.0, td=1.0, sample_time=0.1))
    changed.set_gains(**new)
    built = Pid2Dof(PidConfig(sample_time=0.1, **new))
    for k in range(300):
        r, y = (1.0 if k >= 5 else 0.0), 0.3 * math.sin(0.05 * k)
        assert changed.update(r, y) == built.update(r, y)
    assert changed.rate_step == pytest.approx(0.5 * 0.1)
    assert Pid2Dof(PidConfig()).rate_step is None
    assert changed.limits == (PidConfig().u_min, PidConfig().u_max)


def test_pid_rate_limit_and_limits_hold_every_sample():
    pid = Pid2Dof(PidConfig(kp=50.0, ti=5.0, sample_time=0.5, u_min=-2.0, u_max=3.0,
                            du_max=0.4))
    pid.reset(0.0, 0.0, 0.0)               # from u = 0 (the first sample after it is limited)
    out = [pid.update(1.0, 0.0) for _ in range(40)]
    steps = np.diff([0.0] + out)
    assert np.all(np.abs(steps) <= 0.4 * 0.5 + 1e-15)
    assert max(out) == 3.0 and min(out) >= -2.0


# --------------------------------------------------------------------------- two-loop PI
def test_two_loop_pi_status_before_and_after_a_measurement_fault():
    ctl = TwoLoopPi(document_config('none'))
    assert ctl.status == {}
    ctl.step(0.0, np.array([NAN, 33.0]), np.array([81.0, 33.5]), np.empty(0))
    assert ctl.status == {'input_fault': True}
    ctl.step(1.0, np.array([80.0, 33.0]), np.array([81.0, 33.5]), np.empty(0))
    good = dict(ctl.status)
    assert good['input_fault'] is False and good['r.h'] == 81.0 and good['r.T_out'] == 33.5
    ctl.step(2.0, np.array([80.0, INF]), np.array([81.0, 33.5]), np.empty(0))
    assert ctl.status == {**good, 'input_fault': True}


def test_two_loop_pi_assigned_configuration_acts_like_a_new_controller():
    steps = [(np.array([80.0 + 0.1 * k, 33.0]), np.array([85.0, 34.0 + (k > 20)]))
             for k in range(60)]
    assigned = TwoLoopPi(document_config('none'))
    assigned.config = document_config('static')
    built = TwoLoopPi(document_config('static'))
    for k, (y, r) in enumerate(steps):
        a = assigned.step(float(k), y, r, np.empty(0))
        b = built.step(float(k), y, r, np.empty(0))
        assert a.tolist() == b.tolist()


def test_two_loop_pi_guard_follows_a_changed_setpoint():
    ctl = TwoLoopPi(document_config('none'))
    y = np.array([81.0, 33.5])
    ctl.step(0.0, y, np.array([81.0, 33.5]), np.empty(0))
    assert ctl.status['setpoint_limited'] is False
    ctl.step(1.0, y, np.array([81.0, 70.0]), np.empty(0))     # hotter than T_H: limited
    limited = ctl.status
    assert limited['setpoint_limited'] is True and limited['r.T_out'] < 62.0
    ctl.step(2.0, y, np.array([81.0, 33.5]), np.empty(0))
    assert ctl.status['setpoint_limited'] is False and ctl.status['r.T_out'] == 33.5


# --------------------------------------------------------------------------------- noise
@pytest.mark.parametrize('std', [0.0, 0.5, (0.2, 0.0, 3.0), (0.0, 0.0, 0.0), (1.0, 2.0, 3.0)])
def test_noise_is_std_times_the_seeded_standard_normal_draws(std):
    noise = MeasurementNoise(3, std, seed=7)
    reference = np.random.default_rng(7)
    scale = np.broadcast_to(np.asarray(std, dtype=float), (3,))
    for k in range(1000):           # draws are fetched ahead in batches: cross a few
        z = reference.standard_normal(3)
        expected = [s * v if s > 0 else 0.0 for s, v in zip(scale, z)]
        assert (noise.sample().tolist() if k % 2 else noise.sample_floats()) == expected
    noise.reset()                   # mid-batch: the stream restarts from the seed
    reference = np.random.default_rng(7)
    z = reference.standard_normal(3)
    assert noise.sample().tolist() == [s * v if s > 0 else 0.0 for s, v in zip(scale, z)]


@pytest.mark.parametrize('std', [0.0, 0.5, (0.2, 0.0, 3.0), (1.0, 2.0, 3.0)])
def test_noise_as_floats_is_the_same_stream_and_the_loop_adds_it_as_numpy_does(std):
    # sample_floats (what run_loop gets from core.scenario) draws what sample draws; the loop's
    # float sums equal plant_node's outputs() + sample() bit for bit (-0.0 + 0.0 included)
    from tank_control.core.loop import run_loop
    from tank_control.core.reference import Reference
    a, b = MeasurementNoise(3, std, seed=11), MeasurementNoise(3, std, seed=11)
    for _ in range(50):
        assert a.sample_floats() == b.sample().tolist()

    class Outputs:
        """A 3-output plant whose outputs include -0.0 (every other tick), a large value and
        NaN (every third tick)."""

        output_names, input_names, disturbance_names = ('y', 'a', 'b'), ('u',), ()

        def __init__(self):
            self.k = 0

        def outputs(self):
            return np.array([-0.0 if self.k % 2 else 2.5, 1e300 * (-1) ** self.k,
                             math.nan if self.k % 3 == 0 else 1.0 / (self.k + 1)])

        def step(self, u, d, dt):
            self.k += 1

    class Zero:
        output_names, input_names, disturbance_names = ('y',), ('u',), ()
        sample_time = 0.1

        def reset(self, y, u):
            pass

        def step(self, t, y, r, d):
            return np.array([0.0])

    reference = Reference({'y': ChannelSchedule.constant(0.0)})
    traces = [run_loop(Outputs(), Zero(), reference, sample_time=0.1, duration=2.0,
                       noise=draw)
              for draw in (MeasurementNoise(3, std, seed=5).sample_floats,
                           MeasurementNoise(3, std, seed=5).sample)]
    plant, noise = Outputs(), MeasurementNoise(3, std, seed=5)
    expected = []
    for _ in range(len(traces[0])):
        expected.append(plant.outputs() + noise.sample())      # plant_node's sum
        plant.step(None, None, 0.1)
    for trace in traces:
        for column, name in enumerate(('y.y', 'y.a', 'y.b')):
            got = trace[name]
            want = np.array([row[column] for row in expected])
            assert np.array_equal(got, want, equal_nan=True)
            assert np.array_equal(np.signbit(got), np.signbit(want))


def test_noise_std_is_copied_and_a_live_change_keeps_the_stream():
    std = np.array([1.0, 1.0])
    noise = MeasurementNoise(2, std, seed=3)
    std[:] = 0.0                                    # the caller's array is not the setting
    first = noise.sample()
    assert np.all(first != 0.0)
    noise.set_std([0.0, 2.0])
    reference = np.random.default_rng(3)
    reference.standard_normal(2)
    assert noise.sample().tolist() == [0.0, 2.0 * reference.standard_normal(2)[1]]


# ----------------------------------------------------------------------------- schedules
@pytest.mark.parametrize('schedule', [
    ChannelSchedule(times=(0.0, 10.0, 10.0, 25.0), values=(1.0, 2.0, 3.0, -1.0)),
    ChannelSchedule(times=(0.0, 5.0), values=(0.0, 100.0), ramp_rate=4.0),
    ChannelSchedule(times=(0.0, 5.0, 12.0, 40.0), values=(0.0, 10.0, 3.0, 3.5), ramp_rate=0.7),
    ChannelSchedule.constant(2.5),
])
def test_a_schedule_holds_its_value_until_held_until(schedule):
    grid = [k * 0.05 for k in range(1200)]           # 0 … 60 s
    for t in grid:
        until = schedule.held_until(t)
        assert until >= t
        held = [s for s in grid if t <= s < until]
        assert all(schedule.at(s) == schedule.at(t) for s in held)
    # and it is not a promise of "forever" where the value does change
    changes = [t for a, t in zip(grid, grid[1:]) if schedule.at(t) != schedule.at(a)]
    for t in changes:
        assert any(schedule.held_until(s) <= t for s in grid if s < t)


# ------------------------------------------------------------- tank RK4 written out
def rk4_reference(tank: MixingTank, V: float, T: float, total: float, heat: float, h: float
                  ) -> tuple[float, float, float]:
    """Classical RK4 over ``MixingTank._rhs`` (stages as calls): (V, T, spilled volume)."""
    k1 = tank._rhs(V, T, total, heat)
    k2 = tank._rhs(V + 0.5 * h * k1[0], T + 0.5 * h * k1[1], total, heat)
    k3 = tank._rhs(V + 0.5 * h * k2[0], T + 0.5 * h * k2[1], total, heat)
    k4 = tank._rhs(V + h * k3[0], T + h * k3[1], total, heat)
    return (V + h / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
            T + h / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1]),
            max(h / 6.0 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2]), 0.0))


@pytest.mark.parametrize('h_level', [81.0, 1e-3, 0.0, 199.99, 200.0, 250.0])
@pytest.mark.parametrize('total', [63.0, 0.0, 500.0, 1e6])
@pytest.mark.parametrize('h', [0.5, 1e-3, 7.0])
def test_mixing_tank_rk4_is_rk4_over_its_right_hand_side_bit_for_bit(h_level, total, h):
    # the stages of MixingTank._rk4 are _rhs written out: the same numbers, spill included,
    # at rest, near empty, at and above the brim, with and without inflow
    tank = MixingTank()
    V = tank.config.C * h_level ** 2
    heat = total * 40.0
    for T in (33.5, 0.0, 99.0):
        for given_k1 in (False, True):
            tank._spilled, tank._overflow = 0.0, False
            k1 = tank._rhs(V, T, total, heat) if given_k1 else None
            V_new, T_new = tank._rk4(V, T, total, heat, h, k1)
            V_ref, T_ref, spilled = rk4_reference(tank, V, T, total, heat, h)
            assert (V_new, T_new) == (V_ref, T_ref)
            assert tank._spilled == spilled and tank._overflow == (spilled > 0.0)


# ----------------------------------------------------- loop guards on plant inputs
class RecordingIpdt(Ipdt):
    """An IPDT that records the inputs it is stepped with."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.inputs: list[float] = []

    def step(self, u, d, dt):
        self.inputs.append(np.asarray(u, dtype=float).item())
        super().step(u, d, dt)


class Sequence1:
    """A SISO controller sending ``values`` one per sample (then the last again)."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    sample_time = 0.1
    status: dict = {}

    def __init__(self, values: list[float]) -> None:
        self.values, self.k = values, 0

    def reset(self, y, u):
        pass

    def step(self, t, y, r, d):
        value = self.values[min(self.k, len(self.values) - 1)]
        self.k += 1
        return np.array([value])


@pytest.mark.parametrize('bounds', [(-1.0, 1.0), (-INF, 1.0), (-1.0, INF), None])
def test_loop_guards_take_plant_inputs_as_ranges_accepts_them(bounds):
    # run_loop checks finite ranges by comparison and other ones with Ranges.accepts: either
    # way the plant gets the last input plant_node would have taken
    from tank_control.core.loop import Guards, run_loop
    from tank_control.core.plants.ipdt import IpdtConfig
    from tank_control.core.ranges import Ranges
    from tank_control.core.reference import Reference
    sent = [0.5, 1.0, 1.0000001, -1.0, -0.0, 2.0, -1e300, 0.25, 1e300, -1.5, 0.75]
    plant_ranges = Ranges({} if bounds is None else {'u': bounds})
    plant = RecordingIpdt(IpdtConfig())
    reference = Reference({'y': ChannelSchedule.constant(0.0)})
    run_loop(plant, Sequence1(sent), reference, sample_time=0.1, duration=1.0,
             guards=Guards(plant=plant_ranges, fail_safe_output=(0.0,)))
    expected, good = [], 0.0                              # nominal u = 0 before any output
    for value in sent:
        if plant_ranges.accepts('u', value):
            good = value
        expected.append(good)
    assert len(plant.inputs) == len(sent)
    assert [math.copysign(1.0, v) for v in plant.inputs] == [math.copysign(1.0, v)
                                                             for v in expected]
    assert plant.inputs == expected
