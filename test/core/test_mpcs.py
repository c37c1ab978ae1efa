"""MPCS controller on the nonlinear tank: offset-free tracking, constraints, fallback,
bumpless reset and runtime reconfiguration (in-process)."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tank_control.core.control import mpcs_qp
from tank_control.core.control.kinds import mpcs as mpcs_kind
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.mpcs import Mpcs, MpcsConfig, horizon_warning
from tank_control.core.interfaces import Controller
from tank_control.core.params import ConfigError, config_from, defaults_of, specs_of
from tank_control.core.plants.mixing_tank import MixingTank, MixingTankConfig

T0 = 2115.0 / 63.0     # document's operating temperature ([Michalski2021] §1)
U0 = np.array([14.0, 37.0])
D0 = np.array([12.0, 33.0])


class Tank(MixingTank):
    """The nonlinear tank of core/plants; d = [F_D, T_D] as MPCS measures them."""

    def step(self, u, d, dt):
        super().step(u, [d[0], d[1], 62.0, 23.0], dt)


def make_tank(**kw):
    return Tank(MixingTankConfig(**kw))


def run(ctl, plant, samples, ref, dist, u0=U0):
    """The in-process loop of core/loop.py, reduced: returns y, r, u traces."""
    ctl.reset(plant.outputs(), u0, dist(0.0))
    ys, rs, us = [], [], []
    for k in range(samples):
        t = float(k)
        y, r, d = plant.outputs(), ref(t), dist(t)
        u = ctl.step(t, y, r, d)
        ys.append(y)
        rs.append(r)
        us.append(u)
        plant.step(u, d, 1.0)
    return np.array(ys), np.array(rs), np.array(us)


def scenario_ref(t):
    """h 81 → 84 cm at 0 s, T_out → 35.5 °C at 1200 s."""
    return np.array([84.0, T0 if t < 1200 else 35.5])


def scenario_dist(t):
    """F_D 12 → 15 cm³/s at 2400 s (measured, feed-forward)."""
    return np.array([12.0 if t < 2400 else 15.0, 33.0])


@pytest.mark.parametrize('solver, disturbance_model',
                         [('analytic', 'input'), ('qp', 'input'), ('analytic', 'output')])
def test_offset_free_after_setpoint_and_disturbance_changes(solver, disturbance_model):
    """|e_T| ≤ 0.02 °C and |e_h| ≤ 0.05 cm once settled, on the nonlinear tank, with
    the default horizons and the document's rate limit 0.2 per sample."""
    ctl = Mpcs(MpcsConfig(solver=solver, disturbance_model=disturbance_model))
    y, r, u = run(ctl, make_tank(), 3600, scenario_ref, scenario_dist)
    for end in (1200, 2400, 3600):          # last 150 s before each change / the end
        e = np.abs(y[end - 150:end] - r[end - 150:end])
        assert e[:, 0].max() <= 0.05, (end, e[:, 0].max())
        assert e[:, 1].max() <= 0.02, (end, e[:, 1].max())
    assert ctl.status['fallbacks'] == 0
    assert np.all(np.isfinite(u))


def test_measured_disturbance_feedforward_reduces_the_upset():
    """An F_D step 12 → 18 cm³/s: with F_D, T_D in the prediction both IAEs are smaller."""
    ref = lambda t: np.array([81.0, T0])
    dist = lambda t: np.array([12.0 if t < 10 else 18.0, 33.0])
    iae = {}
    for ff in (True, False):
        y, r, _ = run(Mpcs(MpcsConfig(feedforward=ff)), make_tank(), 1500, ref, dist)
        iae[ff] = np.abs(y - r).sum(axis=0)
    assert np.all(iae[True] < iae[False]), iae


@pytest.mark.parametrize('horizons', [(100, 50, 1), (250, 60, 6)])
def test_constraints_never_violated_with_qp(horizons):
    """Hard input limits and rate limits hold at every sample while saturated
    (also with a horizon beyond the F_Cin dead time and move blocking)."""
    n, nu, block = horizons
    cfg = MpcsConfig(solver='qp', u_min=(5.0, 20.0), u_max=(16.0, 45.0), du_max=(0.1, 0.3),
                     horizon=n, control_horizon=nu, block=block)
    ctl = Mpcs(cfg)
    ref = lambda t: np.array([92.0 if t < 800 else 75.0, 36.0])   # 92 cm needs > 16 cm³/s
    _, _, u = run(ctl, make_tank(), 1600, ref, lambda t: D0)
    du = np.diff(np.vstack([U0, u]), axis=0)
    assert np.all(u >= np.array([5.0, 20.0]) - 1e-9)
    assert np.all(u <= np.array([16.0, 45.0]) + 1e-9)
    assert np.all(np.abs(du) <= np.array([0.1, 0.3]) + 1e-9)
    assert np.isclose(u[:, 0].max(), 16.0)            # the limit was actually reached
    assert ctl.status['fallbacks'] == 0


def test_large_setpoint_change_with_relinearisation():
    """h 81 → 115 cm, T_out → 40 °C, then down to 60 cm / 30 °C, (N, Nu) = (300, 100),
    |Δu| ≤ 2: re-linearising at each setpoint ([Michalski2021] §4's weak point: linearisation
    error for large changes) settles offset-free and with a lower IAE than one
    linearisation at 81 cm."""
    ref = lambda t: np.array([115.0, 40.0]) if t < 1500 else np.array([60.0, 30.0])
    iae = {}
    for relinearize in (True, False):
        cfg = MpcsConfig(solver='qp', horizon=300, control_horizon=100, du_max=(2.0, 2.0),
                         relinearize=relinearize)
        ctl = Mpcs(cfg)
        y, r, _ = run(ctl, make_tank(), 3000, ref, lambda t: D0)
        e = np.abs(y - r)
        iae[relinearize] = e.sum(axis=0)
        assert ctl.status['relinearizations'] == (2 if relinearize else 0)
        if relinearize:
            for end in (1500, 3000):
                assert e[end - 200:end, 0].max() <= 0.05 and e[end - 200:end, 1].max() <= 0.02
    assert np.all(iae[True] < iae[False]), iae


def test_unreachable_temperature_setpoint_does_not_wind_up():
    """[Michalski2021] §2.2's failure mode: T_out = 24 °C with F_D at 33 °C is unreachable at h = 81
    (best: F_H = 0 → T = 24.9 °C). The QP saturates F_H at 0 without windup, the level
    stays at the cost's compromise between the two errors and the loop recovers at once
    when the setpoint becomes reachable again."""
    ref = lambda t: np.array([81.0, 24.0 if t < 1200 else 30.0])
    y, r, u = run(Mpcs(MpcsConfig(solver='qp')), make_tank(), 2600, ref, lambda t: D0)
    # With F_H at 0 only F_Cin is left for two errors: the steady state minimising
    # e_h² + e_T² (W_y = 1, 1) of the linear model ([Michalski2021] eqs. 4-6 at h0 = 81 cm: level gain
    # 2·√h0/α cm, temperature gain (T_C − T0)/q0 °C per cm³/s) raises F_Cin by δ and
    # gives up g_h·δ of level for a little temperature.
    g_h, g_t = 2 * 9.0 / 7.0, (23.0 - T0) / 63.0
    t_best = (51 * 23 + 12 * 33) / 63            # [°C] F_H = 0 at h = 81 cm
    delta = -g_t * (t_best - 24.0) / (g_h ** 2 + g_t ** 2)
    assert y[:1200, 0].max() < 81.2                      # the level never runs away
    assert abs(y[1199, 0] - (81.0 + g_h * delta)) < 0.01, (y[1199, 0], g_h * delta)
    # F_H sits at its lower limit 0: never below it (the output is clipped to the limit), and
    # above it only by the QP's rounding of its active constraint — the QP works in deviations
    # from the operating point (14 cm³/s), where a few ulp are ~1e-15 cm³/s
    assert np.all(u[:, 0] >= 0.0)
    assert 0.0 <= u[1199, 0] <= 1e-12 and abs(y[1199, 1] - t_best) < 0.05
    e = np.abs(y[-150:] - r[-150:])
    assert e[:, 0].max() <= 0.05 and e[:, 1].max() <= 0.02


def test_status_says_which_input_sits_at_its_limit():
    """The unreachable T_out = 24 °C drives F_H to its lower limit 0 (see the test above):
    ``saturated`` is True, for F_H only; at a reachable setpoint nothing is saturated."""
    ctl = Mpcs(MpcsConfig(solver='qp'))
    y, r, u = run(ctl, make_tank(), 1200, lambda t: np.array([81.0, 24.0]), lambda t: D0)
    assert u[-1, 0] <= 1e-12                              # F_H at 0 cm³/s
    status = ctl.status
    assert status['saturated'] is True
    assert status['saturated.F_H'] is True and status['saturated.F_Cin'] is False
    ctl = Mpcs(MpcsConfig(solver='qp'))
    run(ctl, make_tank(), 600, lambda t: np.array([81.0, T0]), lambda t: D0)
    assert ctl.status['saturated'] is False


def test_analytic_and_qp_agree_when_no_constraint_is_active():
    base = MpcsConfig(du_max=(100.0, 100.0), u_min=(0.0, 0.0), u_max=(500.0, 500.0))
    ref = lambda t: np.array([81.5, T0 + 0.2])
    traces = []
    for solver in ('analytic', 'qp'):
        ctl = Mpcs(replace(base, solver=solver))
        traces.append(run(ctl, make_tank(), 400, ref, lambda t: D0)[2])
        assert ctl.status['fallbacks'] == 0
    np.testing.assert_allclose(traces[0], traces[1], atol=1e-6)


def test_infeasible_qp_falls_back_to_the_clipped_analytic_move():
    """Started 20 cm³/s above u_max with a 0.2 rate limit the QP is infeasible: the
    fallback is used, counted, and the hard limits still win."""
    ctl = Mpcs(MpcsConfig(solver='qp'))
    plant = make_tank()
    ctl.reset(plant.outputs(), np.array([120.0, 37.0]), D0)
    u = ctl.step(0.0, plant.outputs(), np.array([81.0, T0]), D0)
    assert ctl.status['fallbacks'] == 1
    assert np.all(np.isfinite(u)) and u[0] == 100.0


def test_solver_failures_never_publish_nan(monkeypatch):
    """A solver that returns NaN, or gives up at its iteration limit, falls back."""
    class NanModel:
        settings = {}

        def setup(self, *args):
            return 1, 0.0

        def update(self, **kw):
            pass

        def solve(self):
            return np.full(100, np.nan), np.nan, 1, {'iterations': 1}

    class FakeDaqp:
        Model = NanModel

    monkeypatch.setattr(mpcs_qp, 'daqp', FakeDaqp)
    ctl = Mpcs(MpcsConfig(solver='qp'))
    _, _, u = run(ctl, make_tank(), 50, lambda t: np.array([83.0, 34.0]), lambda t: D0)
    assert np.all(np.isfinite(u)) and ctl.status['fallbacks'] == 50
    monkeypatch.undo()
    ctl = Mpcs(MpcsConfig(solver='qp', qp_iter_limit=1, du_max=(0.05, 0.05)))
    _, _, u = run(ctl, make_tank(), 50, lambda t: np.array([90.0, 30.0]), lambda t: D0)
    assert np.all(np.isfinite(u)) and ctl.status['fallbacks'] > 0
    assert np.all(np.abs(np.diff(u, axis=0)) <= 0.05 + 1e-12)


def test_non_finite_measurement_or_setpoint_never_reaches_the_output():
    ctl = Mpcs(MpcsConfig(solver='qp'))
    ctl.reset(np.array([81.0, T0]), U0, D0)
    u1 = ctl.step(0.0, np.array([np.nan, T0]), np.array([82.0, T0]), D0)
    u2 = ctl.step(1.0, np.array([81.0, T0]), np.array([np.nan, T0]), np.array([np.inf, 33.0]))
    assert np.all(np.isfinite(u1)) and np.array_equal(u2, u1)
    assert ctl.status['bad_measurements'] == 1 and ctl.status['bad_setpoints'] == 1


def test_bumpless_reset_away_from_the_operating_point():
    """At another equilibrium (u = (16, 37)) with r = y the input does not move."""
    u_eq = np.array([16.0, 37.0])
    q = 16 + 37 + 12
    h_eq, t_eq = (q / 7.0) ** 2, (16 * 62 + 37 * 23 + 12 * 33) / q
    plant = make_tank(initial_h=h_eq, initial_T=t_eq)
    ctl = Mpcs(MpcsConfig(solver='qp'))
    _, _, u = run(ctl, plant, 300, lambda t: np.array([h_eq, t_eq]), lambda t: D0, u0=u_eq)
    assert np.abs(u - u_eq).max() < 1e-6


def test_reset_without_disturbance_takes_the_first_measured_one():
    """reset(y, u) (the Controller protocol's signature) while F_D = 16 is already
    flowing: the first step must not treat F_D as a 12 → 16 step."""
    q = 14 + 37 + 16
    h_eq, t_eq = (q / 7.0) ** 2, (14 * 62 + 37 * 23 + 16 * 33) / q
    plant = make_tank(initial_h=h_eq, initial_T=t_eq)
    ctl = Mpcs(MpcsConfig(solver='analytic'))
    ctl.reset(plant.outputs(), U0)
    d = np.array([16.0, 33.0])
    for k in range(200):
        u = ctl.step(float(k), plant.outputs(), np.array([h_eq, t_eq]), d)
        assert np.abs(u - U0).max() < 1e-6
        plant.step(u, d, 1.0)
    ctl.reset(np.array([np.nan, 30.0]), np.array([np.inf, 37.0]))    # never NaN after this
    assert np.all(np.isfinite(ctl.step(0.0, plant.outputs(), np.array([h_eq, t_eq]), d)))


def test_configure_at_runtime_keeps_sampling_and_rejects_bad_values():
    ctl = Mpcs(MpcsConfig(solver='analytic'))
    plant = make_tank()
    ctl.reset(plant.outputs(), U0, D0)
    ref = lambda t: np.array([83.0, 34.5])
    u = U0
    for k in range(3000):
        if k == 500:     # mid-transient: new horizons, weights and solver
            ctl.configure(**{'mpcs.horizon': 250, 'mpcs.control_horizon': 20,
                             'mpcs.lambda': [1.0, 2.0], 'mpcs.solver': 'qp'})
        if k == 1000:    # new operating point: estimator restarts bumplessly
            u_before = u
            ctl.configure(op_F_H=15.0, op_F_Cin=38.0)
        y = plant.outputs()
        u = ctl.step(float(k), y, ref(k), D0)
        if k == 1000:
            assert np.all(np.abs(u - u_before) <= 0.2 + 1e-12)
        plant.step(u, D0, 1.0)
    assert ctl.config.horizon == 250 and ctl.status['solver'] == 'qp'
    assert ctl.status['rebuilds'] == 2
    assert abs(plant.outputs()[0] - 83.0) < 0.05 and abs(plant.outputs()[1] - 34.5) < 0.02
    for bad, name in (({'mpcs.horizon': 0}, 'mpcs.horizon'),
                      ({'mpcs.control_horizon': 400}, 'mpcs.control_horizon'),
                      ({'mpcs.solver': 'lp'}, 'mpcs.solver'),
                      ({'mpcs.u_min': [50.0, 50.0], 'mpcs.u_max': [40.0, 60.0]}, 'mpcs.u_min'),
                      ({'mpcs.nonsense': 1}, 'mpcs.nonsense'),
                      ({'mpcs.op.F_H': 0.0, 'mpcs.op.F_Cin': 0.0, 'mpcs.op.F_D': 0.0},
                       'mpcs.op.F_H')):
        with pytest.raises(ValueError, match=name.replace('.', r'\.')):
            ctl.configure(**bad)
    assert ctl.config.horizon == 250 and ctl.config.solver == 'qp'


def test_soft_output_bound_limits_the_level():
    """A soft upper bound of 83 cm on h overrides a setpoint of 86 cm (qp only)."""
    cfg = MpcsConfig(solver='qp', soft_bounds=True, y_max=(83.0, 100.0), soft_weight=1e5)
    y, _, _ = run(Mpcs(cfg), make_tank(), 1500, lambda t: np.array([86.0, T0]),
                  lambda t: D0)
    assert y[:, 0].max() < 83.1 and y[-1, 0] > 82.5


def test_params_describe_the_config_and_reject_with_reasons():
    specs = specs_of(MpcsConfig)
    names = {s.name for s in specs}
    assert {'mpcs.horizon', 'mpcs.control_horizon', 'mpcs.lambda', 'mpcs.solver',
            'mpcs.u_min', 'mpcs.u_max', 'mpcs.du_max', 'mpcs.output_weights',
            'mpcs.op.F_H', 'mpcs.op.F_Cin'} <= names
    assert all(s.description and s.check(s.default) is None for s in specs)
    assert config_from(MpcsConfig, defaults_of(MpcsConfig)) == MpcsConfig()
    with pytest.raises(ConfigError, match=r'mpcs\.lambda.*below the minimum'):
        config_from(MpcsConfig, {'mpcs.lambda': [-1.0]})
    assert config_from(MpcsConfig, {'mpcs.lambda': 0.3}).lam == (0.3,)   # one value for both


def test_is_a_controller():
    ctl = Mpcs()
    assert isinstance(ctl, Controller)
    assert ctl.output_names == ('h', 'T_out') and ctl.input_names == ('F_H', 'F_Cin')
    assert ctl.disturbance_names == ('F_D', 'T_D') and ctl.sample_time == 1.0


def test_controller_kind_builds_checks_and_updates_from_parameter_values():
    """resolve/build/update from flat parameter values, as controller_node drives them."""
    kind = mpcs_kind.KIND
    values = {'mpcs.solver': 'qp', 'mpcs.horizon': 80, 'mpcs.control_horizon': 30}
    resolve(kind, values)                  # [Michalski2021] §6's (80, 30): accepted (with a warning)
    ctl = kind.build(resolve(kind, values))
    assert ctl.config.solver == 'qp' and ctl.config.horizon == 80
    with pytest.raises(ConfigError, match='mpcs.control_horizon'):
        resolve(kind, {**values, 'mpcs.control_horizon': 90})
    values.update({'mpcs.control_horizon': 20, 'mpcs.lambda': [0.3]})
    kind.update(ctl, resolve(kind, values), frozenset({'mpcs.control_horizon', 'mpcs.lambda'}))
    assert ctl.config.control_horizon == 20 and ctl.config.lam == (0.3,)


def test_runs_in_the_project_loop_from_an_off_nominal_start():
    """core/loop.py (no reset call): the first step initialises from the measurement;
    the tank starts at 78 cm / 32 °C and settles at the setpoints of the reference."""
    from tank_control.core.loop import run_loop
    from tank_control.core.reference import ChannelSchedule, Reference
    plant = MixingTank(MixingTankConfig(initial_h=78.0, initial_T=32.0))
    reference = Reference(
        setpoints={'h': ChannelSchedule.constant(82.0), 'T_out': ChannelSchedule.constant(34.0)},
        disturbances={'F_D': ChannelSchedule(times=(0.0, 600.0), values=(12.0, 14.0))})
    trace = run_loop(plant, Mpcs(MpcsConfig(solver='qp')), reference, sample_time=1.0,
                     duration=2000.0)
    assert np.all(np.isfinite(trace['u.F_H'])) and np.all(np.isfinite(trace['u.F_Cin']))
    assert np.abs(trace['y.h'][-150:] - 82.0).max() <= 0.05
    assert np.abs(trace['y.T_out'][-150:] - 34.0).max() <= 0.02


def test_registered_kind_is_built_checked_and_reconfigured_by_the_registry():
    """``controller: mpcs`` is a registered kind: resolve / build / step_with_changes (what
    controller_node and the in-process loop call) drive MPCS."""
    from tank_control.core.control.kinds import registry
    kind = registry.get_kind('mpcs')
    values = {'mpcs.solver': 'qp'}
    ctl = registry.build(kind, resolve(kind, values))
    assert isinstance(ctl, Mpcs) and ctl.config.solver == 'qp'
    with pytest.raises(ConfigError, match='mpcs.horizon'):
        resolve(kind, {**values, 'mpcs.horizon': 0})
    y, r = np.array([81.0, T0]), np.array([82.0, T0])
    same, u = registry.step_with_changes(kind, ctl, resolve(kind, {**values, 'mpcs.horizon': 700}),
                                         frozenset({'mpcs.horizon'}), 0.0, y, r, D0)
    assert same is ctl and ctl.config.horizon == 700 and np.all(np.isfinite(u))


def test_unmeasured_disturbance_channels_use_the_operating_point_then_the_last_value():
    """A disturbance channel the reference does not publish arrives as NaN (controller_node):
    MPCS uses mpcs.op.F_D / mpcs.op.T_D until a value is measured, then the last measured one;
    the output is never NaN."""
    op = MpcsConfig(op_F_D=12.0, op_T_D=33.0)
    y, r = np.array([81.0, 33.6]), np.array([82.0, 34.0])
    a, b = Mpcs(op), Mpcs(op)
    for k in range(5):
        ua = a.step(float(k), y, r, np.array([np.nan, np.nan]))
        ub = b.step(float(k), y, r, np.array([12.0, 33.0]))
        assert np.all(np.isfinite(ua)) and np.array_equal(ua, ub)
    # F_D measured once (15), then missing again: 15 is kept, T_D stays at the operating point
    ua = a.step(5.0, y, r, np.array([15.0, np.nan]))
    ub = b.step(5.0, y, r, np.array([15.0, 33.0]))
    assert np.array_equal(ua, ub)
    ua = a.step(6.0, y, r, np.array([np.nan, np.nan]))
    ub = b.step(6.0, y, r, np.array([15.0, 33.0]))
    assert np.array_equal(ua, ub)


# --- horizons: the defaults cover the dead times; shorter ones are accepted with a warning ---

#: [s] time constant of the level at the document's operating point, from V = C·h² and
#: F = α·√h linearised at h0 = 81 cm: τ = 4·C·h0^1.5/α ([Michalski2021] §1; the slowest mode of the model)
TAU_LEVEL = 4 * 0.7 * 81.0 ** 1.5 / 7.0
F_CIN_DELAY = 180          # [samples] the cold-water dead time at Ts = 1 s ([Michalski2021] §1)
CHANGES = (100, 1600, 3100)         # [s] h step, T_out step, F_D step, 1500 s apart
SETTLED = 1200             # [s] after a change the claim holds from here to the next change


def sequence_ref(t):
    """h 81 → 85 cm at 100 s, T_out → 35.5 °C at 1600 s."""
    return np.array([81.0 if t < 100 else 85.0, T0 if t < 1600 else 35.5])


def sequence_dist(t):
    """F_D 12 → 15 cm³/s at 3100 s (measured)."""
    return np.array([12.0 if t < 3100 else 15.0, 33.0])


def settled_errors(y, r):
    """Worst |e_h| [cm] and |e_T| [°C] from SETTLED s after each change to the next one."""
    ends = CHANGES[1:] + (len(y),)
    e = np.abs(y - r)
    return np.max([e[c + SETTLED:end].max(axis=0) for c, end in zip(CHANGES, ends)], axis=0)


@pytest.mark.parametrize('weights, lam, solver', [
    ((1.0, 30.0), 0.5, 'qp'),          # the T_out weight raised to 30
    ((1.0, 30.0), 0.5, 'analytic'),
    ((30.0, 1.0), 0.5, 'qp'),          # the level weight raised instead
    ((1.0, 100.0), 0.1, 'qp'),
    ((100.0, 1.0), 1.0, 'qp'),
])
def test_default_horizons_settle_offset_free_with_unequal_weights(weights, lam, solver):
    """The claim |e_h| ≤ 0.05 cm, |e_T| ≤ 0.02 °C (from 1200 s after each change) holds with
    the default horizons for strongly unequal output weights and [Michalski2021]'s range of λ, within
    the rate limit 0.2 cm³/s per sample; the defaults give no warning."""
    ctl = Mpcs(MpcsConfig(solver=solver, output_weights=weights, lam=(lam,)))
    assert ctl.warning == ''
    y, r, u = run(ctl, make_tank(), 4600, sequence_ref, sequence_dist)
    e_h, e_t = settled_errors(y, r)
    assert e_h <= 0.05 and e_t <= 0.02, (e_h, e_t)
    assert np.all(np.abs(np.diff(np.vstack([U0, u]), axis=0)) <= 0.2 + 1e-9)


def test_document_horizons_warn_and_leave_the_level_off_with_a_heavy_temperature_weight():
    """[Michalski2021] §6's (N, Nu) = (100, 50) with W_y = (1, 30): accepted with a warning naming both
    horizons, and 1200 s after the h step the level is still more than 0.05 cm off (moving
    h at a fixed T needs F_Cin, which acts only after 180 s, beyond every planned move)."""
    ctl = Mpcs(MpcsConfig(solver='qp', horizon=100, control_horizon=50, block=1,
                          output_weights=(1.0, 30.0)))
    assert 'mpcs.horizon' in ctl.warning and 'mpcs.control_horizon' in ctl.warning
    y, _, _ = run(ctl, make_tank(), CHANGES[0] + SETTLED + 1, sequence_ref, sequence_dist)
    assert abs(y[-1, 0] - 85.0) > 0.05


def test_horizon_warning_names_each_parameter_and_its_minimum():
    n_min = F_CIN_DELAY + math.ceil(TAU_LEVEL)            # 180 + 292 samples
    assert horizon_warning(MpcsConfig()) == ''
    short = horizon_warning(MpcsConfig(horizon=n_min - 1))
    assert short.startswith('mpcs.horizon: ') and f'at least {n_min} ' in short
    assert '\n' not in short and 'mpcs.control_horizon' not in short
    assert horizon_warning(MpcsConfig(horizon=n_min)) == ''
    # without alignment the cost looks through F_Cin's 180 s and T_out's 120 s
    assert f'at least {300 + math.ceil(TAU_LEVEL)} ' in horizon_warning(
        MpcsConfig(align=False, horizon=n_min))
    # another operating point: its own level time constant (h0 = ((16 + 37 + 12)/7)²)
    h0 = ((16.0 + 37.0 + 12.0) / 7.0) ** 2
    n_op = F_CIN_DELAY + math.ceil(4 * 0.7 * h0 ** 1.5 / 7.0)
    assert f'at least {n_op} ' in horizon_warning(MpcsConfig(op_F_H=16.0, horizon=n_op - 1))
    assert horizon_warning(MpcsConfig(op_F_H=16.0, horizon=n_op)) == ''
    # control horizon: the last planned move, at (⌈Nu/block⌉ − 1)·block, after F_Cin's 180 s
    for block in (1, 7, 10, 20):
        nu_min = next(nu for nu in range(1, 600)
                      if (math.ceil(nu / block) - 1) * block > F_CIN_DELAY)
        few = horizon_warning(MpcsConfig(control_horizon=nu_min - 1, block=block))
        assert few.startswith('mpcs.control_horizon: ')
        assert f'at least {nu_min} with mpcs.block {block}' in few
        assert horizon_warning(MpcsConfig(control_horizon=nu_min, block=block)) == ''


@pytest.mark.parametrize('solver, n, nu, lam', [
    ('analytic', 50, 10, 1.0), ('analytic', 300, 100, 0.1), ('analytic', 500, 60, 0.4),
    ('qp', 100, 50, 0.5), ('qp', 50, 10, 0.2), ('qp', 80, 30, 0.3)])   # [Michalski2021] §4, §6
def test_the_documents_settings_are_accepted_with_a_warning(solver, n, nu, lam):
    values = {'mpcs.solver': solver, 'mpcs.horizon': n, 'mpcs.control_horizon': nu,
              'mpcs.block': 1, 'mpcs.lambda': [lam]}
    ctl = Mpcs(config_from(MpcsConfig, values))      # not refused
    assert 'mpcs.control_horizon' in ctl.warning      # every Nu ≤ 100: before F_Cin acts
    assert ctl.status['warning'] == ctl.warning and ctl.status['warnings'] == 1
    _, _, u = run(ctl, make_tank(), 50, lambda t: np.array([82.0, T0]), lambda t: D0)
    assert np.all(np.isfinite(u)) and np.all(np.abs(np.diff(u, axis=0)) <= 0.2 + 1e-9)


def test_status_shows_the_warning_of_the_design_in_use_and_counts_them():
    ctl = Mpcs()
    assert ctl.status['warning'] == '' and ctl.status['warnings'] == 0
    ctl.configure(horizon=300)
    assert ctl.status['warning'].startswith('mpcs.horizon') and ctl.status['warnings'] == 1
    ctl.configure(horizon=600)
    assert ctl.status['warning'] == '' and ctl.status['warnings'] == 1


def test_an_output_dead_time_beyond_the_estimators_register_is_refused_with_the_cost():
    """mpcs.model.tau of 3600 s at 1 s would take minutes to design (the Riccati equation grows
    with the cube of the delay register): refused before anything is built, naming the bound
    in samples and in seconds at the current sample time; the bound itself is accepted."""
    from tank_control.core.control.kinds import registry
    from tank_control.core.control.kinds.base import resolve
    from tank_control.core.control.mpcs import MAX_OUTPUT_DELAY_SAMPLES
    from tank_control.core.params import ConfigError
    kind = registry.KINDS['mpcs']
    with pytest.raises(ConfigError, match=r'mpcs.model.tau: 3600 s is 3600 samples at '
                                          r'sample_time 1 s; .* at most 900 s'):
        resolve(kind, {'mpcs.model.tau': 3600.0})
    with pytest.raises(ConfigError, match='at most 450 s'):
        resolve(kind, {'mpcs.model.tau': 600.0, 'sample_time': 0.5})
    bound = float(MAX_OUTPUT_DELAY_SAMPLES)
    assert resolve(kind, {'mpcs.model.tau': bound}).values['mpcs.model.tau'] == bound
