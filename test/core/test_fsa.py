"""The FSA controller ([Precup2013] §3.6.2, eqs. 3.6.10–3.6.15; core/control/fsa.py) on stable and
unstable first-order plants with dead time: the assigned poles, the exact prediction, the
designed step response, integral action, robustness, a safe implementation of the
prediction, limits, bumpless operation and refused parameters."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.control.fsa import FsaConfig, FsaController, design
from tank_control.core.control.kinds import registry
from tank_control.core.params import ConfigError
from tank_control.core.plants.fopdt import Fopdt, FopdtConfig
from tank_control.core.plants.foupdt import Foupdt, FoupdtConfig

PLANTS = {'fopdt': (Fopdt, FopdtConfig), 'foupdt': (Foupdt, FoupdtConfig)}


def plant_of(model: str, gain: float, time_constant: float, dead_time: float):
    cls, config = PLANTS[model]
    return cls(config(gain=gain, time_constant=time_constant, dead_time=dead_time))


def closed_loop(controller, plant, t_end: float, r_of_t=lambda t: 1.0 if t >= 1.0 else 0.0,
                v_of_t=lambda t: 0.0) -> dict[str, np.ndarray]:
    """Plant and controller sampled together every ``sample_time`` (ZOH output), controller
    taken over at rest with u = 0; rows t, y, r, u, prediction."""
    h = controller.sample_time
    controller.reset(np.array([plant.outputs()[0]]), np.array([0.0]))
    rows = []
    for k in range(int(round(t_end / h)) + 1):
        t = k * h
        y, r = plant.outputs()[0], r_of_t(t)
        u = controller.step(t, np.array([y]), np.array([r]), np.array([]))[0]
        rows.append((t, y, r, u, controller.status['prediction']))
        plant.step(np.array([u]), np.array([v_of_t(t)]), h)
    out = np.array(rows)
    return dict(zip(('t', 'y', 'r', 'u', 'prediction'), out.T))


def second_order_step(w0: float, xi: float, t: np.ndarray) -> np.ndarray:
    """Unit step response of ω0²/p(s), p(s) = s² + 2ξω0·s + ω0² ([Precup2013] eq. 3.6.12), ξ < 1."""
    t = np.maximum(t, 0.0)
    wd = w0 * math.sqrt(1.0 - xi * xi)
    return 1.0 - np.exp(-xi * w0 * t) / math.sqrt(1.0 - xi * xi) * np.sin(wd * t + math.acos(xi))


def settling_time(t: np.ndarray, y: np.ndarray, final: float, band: float = 0.02) -> float:
    outside = np.nonzero(np.abs(y - final) > band * abs(final))[0]
    return float(t[outside[-1] + 1])


CASES = [  # model, K, T, L, omega0, xi, h
    ('fopdt', 1.0, 10.0, 5.0, 0.2, 0.7, 0.1),
    ('foupdt', 1.0, 10.0, 5.0, 0.2, 0.7, 0.1),
    ('fopdt', -0.5, 8.0, 3.37, 0.25, 0.5, 0.1),    # fractional dead time, reverse acting
    ('foupdt', 2.0, 8.0, 3.37, 0.25, 0.8, 0.1),
    ('foupdt', 1.0, 4.0, 0.05, 0.5, 0.7, 0.1),      # dead time below one sample
]


def config_of(case, **changes) -> FsaConfig:
    model, k, t, l, w0, xi, h = case
    return FsaConfig(model=model, gain=k, time_constant=t, dead_time=l, omega0=w0, xi=xi,
                     sample_time=h, **changes)


# ------------------------------------------------------------------------------- design
@pytest.mark.parametrize('case', CASES)
def test_the_diophantine_solution_assigns_exactly_the_poles_of_p(case):
    """[Precup2013] eq. 3.6.12: the predicted loop's poles are e^(s·h) at the roots s of
    s² + 2ξω0·s + ω0² (and 0), computed here independently of the design's own check."""
    cfg = config_of(case)
    des = design(cfg)
    a, b = des.matrices(cfg.sample_time)
    closed = np.linalg.eigvals(a - np.outer(b, des.gains))
    roots = np.roots([1.0, 2.0 * cfg.xi * cfg.omega0, cfg.omega0 ** 2])
    expected = np.concatenate([np.exp(roots * cfg.sample_time), [0.0]])
    np.testing.assert_allclose(np.sort_complex(closed), np.sort_complex(expected), atol=1e-9)


@pytest.mark.parametrize('model', ['fopdt', 'foupdt'])
def test_the_sampled_gains_tend_to_the_continuous_fsa_law(model):
    """h → 0: F_ξ → f1 = (2ξω0 + α)/β, F_ζ → f2 = −ω0²/β; the integral gain ω0²·T/K is the
    h1 of [Precup2013] eq. 3.6.15, h(s) = ω0²(1 + s·T)/K."""
    cfg = FsaConfig(model=model, gain=2.0, time_constant=10.0, dead_time=4.0, omega0=0.3,
                    xi=0.8, sample_time=0.001)
    des = design(cfg)
    alpha = 0.1 if model == 'foupdt' else -0.1
    f1, f2 = (2 * 0.8 * 0.3 + alpha) / 0.2, -0.09 / 0.2
    assert des.continuous == pytest.approx((f1, f2), rel=1e-12)
    assert -f2 == pytest.approx(0.3 ** 2 * 10.0 / 2.0)
    assert des.gains[0] == pytest.approx(f1, rel=5e-3)
    assert des.gains[1] == pytest.approx(f2, rel=5e-3)


@pytest.mark.parametrize('case', CASES)
def test_the_prediction_is_the_output_one_dead_time_ahead(case):
    """ξ(k) = x(k + d) on the matching model, L = (d + f)·h (f: the rest of a sample)."""
    cfg = config_of(case)
    d = design(cfg).d
    run = closed_loop(FsaController(cfg), plant_of(*case[:4]), 40.0,
                      v_of_t=lambda t: 0.0)
    np.testing.assert_allclose(run['prediction'][:len(run['y']) - d], run['y'][d:],
                               rtol=0.0, atol=1e-12)


# -------------------------------------------------------------------- closed loop, exact
@pytest.mark.parametrize('case', CASES[:4])
def test_the_setpoint_response_is_the_designed_second_order_one_delayed_by_l(case):
    """On the matching model y follows ω0²/p(s)·e^(−L·s): overshoot within 0.05 points of
    exp(−πξ/√(1 − ξ²)), 2 % settling within two samples of the continuous response's, the
    whole trace within 0.01 (the hold's half sample and the discrete integral)."""
    cfg = config_of(case)
    t_end = 1.0 + cfg.dead_time + 12.0 / (cfg.xi * cfg.omega0)
    run = closed_loop(FsaController(cfg), plant_of(*case[:4]), t_end)
    t, y = run['t'], run['y'] / 1.0
    sign_free = y                                   # setpoint 1: y → 1 for any sign of K
    designed = second_order_step(cfg.omega0, cfg.xi, t - 1.0 - cfg.dead_time)
    assert np.max(np.abs(sign_free - designed)) < 0.01
    overshoot = 100.0 * math.exp(-math.pi * cfg.xi / math.sqrt(1 - cfg.xi ** 2))
    assert 100.0 * (y.max() - 1.0) == pytest.approx(overshoot, abs=0.05)
    fine = np.linspace(0.0, t_end, 400_001)
    expected = settling_time(fine, second_order_step(cfg.omega0, cfg.xi,
                                                     fine - 1.0 - cfg.dead_time), 1.0)
    assert settling_time(t, y, 1.0) == pytest.approx(expected, abs=2 * cfg.sample_time + 1e-9)
    assert abs(y[-1] - 1.0) < 1e-4


@pytest.mark.parametrize('case', CASES[:4])
def test_integral_action_rejects_a_load_step_without_steady_state_error(case):
    cfg = config_of(case)
    t_load = 1.0 + cfg.dead_time + 12.0 / (cfg.xi * cfg.omega0)
    run = closed_loop(FsaController(cfg), plant_of(*case[:4]), 2 * t_load,
                      v_of_t=lambda t: 0.2 if t >= t_load else 0.0)
    after = run['t'] >= t_load
    deviation = np.abs(run['y'][after] - 1.0)
    assert deviation.max() > 0.02                      # the load was felt …
    assert deviation[-20:].max() < 1e-4                # … and removed
    # the output ends where the load is compensated: u + v = the input for y = 1
    static = -case[1] if case[0] == 'foupdt' else case[1]
    assert run['u'][-1] + 0.2 == pytest.approx(1.0 / static, abs=1e-4)


@pytest.mark.parametrize('model', ['fopdt', 'foupdt'])
@pytest.mark.parametrize('plant_change', [{'gain': 1.1}, {'gain': 0.9},
                                          {'time_constant': 11.0}, {'time_constant': 9.0},
                                          {'dead_time': 5.5}, {'dead_time': 4.5}])
def test_a_modest_model_error_keeps_the_loop_stable_without_offset(model, plant_change):
    """±10 % in the plant's K, T or L against the model (K 1, T 10 s, L 5 s; ω0 0.2, ξ 0.7):
    still stable, no steady-state error, overshoot below 20 % (measured ≤ 15.9 %, the
    unstable plant with K −10 %)."""
    cfg = FsaConfig(model=model, gain=1.0, time_constant=10.0, dead_time=5.0, omega0=0.2,
                    xi=0.7, sample_time=0.1)
    values = {'gain': 1.0, 'time_constant': 10.0, 'dead_time': 5.0, **plant_change}
    run = closed_loop(FsaController(cfg), plant_of(model, **values), 300.0)
    assert run['y'].max() - 1.0 < 0.2
    assert np.max(np.abs(run['y'][-500:] - 1.0)) < 1e-6


# --------------------------------------------------------- a safe implementation (unstable)
class RecursivePrediction(FsaController):
    """The same law with the prediction's window sum updated recursively,
    W(k+1) = u(k) + φ·(W(k) − φ^(d−1)·u(k−d)) (L a whole number of samples): the textbook
    shortcut, which keeps the model pole φ = e^(h/T) > 1 inside the controller."""

    def _predict(self, y, r_sum):
        des = self._des
        if not hasattr(self, '_w'):
            history = list(self._u_hist)
            self._w = sum(des.phi ** i * history[i] for i in range(des.d))
        xi = des.phi ** des.d * y + des.g0 * self._w
        _, ahead, u_prev = super()._predict(y, r_sum)
        return xi, ahead, u_prev

    def _advance(self, u, r):
        leaving = self._u_hist[self._des.d - 1]        # u(k − d)
        super()._advance(u, r)
        if hasattr(self, '_w'):
            phi = self._des.phi
            self._w = u + phi * (self._w - phi ** (self._des.d - 1) * leaving)


def test_the_prediction_is_an_fir_sum_that_stays_exact_where_a_recursive_one_diverges():
    """Unstable plant, T = 10 s, L = 5 s, 600 s = 60 T: rounding errors in a recursive window
    sum grow like e^(t/T) (10^26 here) and the loop is lost; the FIR sums the controller
    evaluates every sample keep y at the setpoint to 1e-12."""
    cfg = FsaConfig(model='foupdt', gain=1.0, time_constant=10.0, dead_time=5.0, omega0=0.2,
                    xi=0.7, sample_time=0.1)
    ours = closed_loop(FsaController(cfg), plant_of('foupdt', 1.0, 10.0, 5.0), 600.0)
    assert np.max(np.abs(ours['y'][ours['t'] > 200.0] - 1.0)) < 1e-12
    assert np.max(np.abs(ours['prediction'][ours['t'] > 200.0] - 1.0)) < 1e-12
    recursive = closed_loop(RecursivePrediction(cfg), plant_of('foupdt', 1.0, 10.0, 5.0), 600.0)
    assert np.max(np.abs(recursive['y'][:2000] - ours['y'][:2000])) < 1e-6   # same law …
    assert np.max(np.abs(recursive['y'] - 1.0)) > 1.0                        # … lost later


# ------------------------------------------------------------------ limits, anti-windup
def _saturated_run(anti_windup: str) -> dict[str, np.ndarray]:
    cfg = FsaConfig(model='fopdt', gain=1.0, time_constant=10.0, dead_time=5.0, omega0=0.3,
                    xi=0.7, sample_time=0.1, u_min=-1.5, u_max=1.5, anti_windup=anti_windup)
    return closed_loop(FsaController(cfg), plant_of('fopdt', 1.0, 10.0, 5.0), 120.0)


def test_the_output_respects_the_limits_and_anti_windup_cuts_the_overshoot():
    runs = {m: _saturated_run(m) for m in ('back_calculation', 'conditional_integration', 'none')}
    for run in runs.values():
        assert run['u'].max() == 1.5 and run['u'].min() >= -1.5
        assert abs(run['y'][-1] - 1.0) < 1e-3
    overshoot = {m: run['y'].max() - 1.0 for m, run in runs.items()}
    assert overshoot['back_calculation'] < 0.5 * overshoot['none']
    assert overshoot['conditional_integration'] < 0.5 * overshoot['none']


def test_the_prediction_runs_on_the_limited_output():
    """Saturated for a while, the prediction still equals the output one dead time ahead."""
    run = _saturated_run('back_calculation')
    d = 50
    np.testing.assert_allclose(run['prediction'][:-d], run['y'][d:], rtol=0.0, atol=1e-12)


# -------------------------------------------------------------------- bumpless operation
def _running(cfg: FsaConfig, t_end: float = 30.0):
    controller, plant = FsaController(cfg), plant_of(cfg.model, cfg.gain, cfg.time_constant,
                                                     cfg.dead_time)
    closed_loop(controller, plant, t_end)
    return controller, plant


def _step(controller, plant, t, r=1.0):
    return controller.step(t, plant.outputs(), np.array([r]), np.array([]))[0]


def test_reset_makes_the_next_output_the_given_one():
    cfg = config_of(CASES[1])
    controller = FsaController(cfg)
    controller.reset(np.array([0.3]), np.array([-0.7]))
    assert controller.step(0.0, np.array([0.3]), np.array([1.0]), np.array([]))[0] == \
        pytest.approx(-0.7, abs=1e-12)
    controller.reset(np.array([0.3]), np.array([1e12]))          # clipped to the limits
    assert controller.step(0.1, np.array([0.3]), np.array([1.0]), np.array([]))[0] == 1e9


@pytest.mark.parametrize('changes', [{'omega0': 0.3}, {'xi': 1.2}, {'omega0': 0.1, 'xi': 0.5}])
def test_a_change_of_the_design_is_bumpless(changes):
    """At the same inputs the next output is the one the old settings would give."""
    cfg = config_of(CASES[1])
    controller, plant = _running(cfg)
    twin = FsaController(cfg)
    twin.__dict__.update({k: (v.copy() if hasattr(v, 'copy') else v)
                          for k, v in controller.__dict__.items()})
    expected = _step(twin, plant, 30.1)
    controller.set_gains(**changes)
    assert _step(controller, plant, 30.1) == pytest.approx(expected, abs=1e-12)
    assert controller.design.poles != twin.design.poles


def test_manual_and_back_to_auto_are_bumpless_and_the_prediction_keeps_running():
    cfg = config_of(CASES[1])
    controller, plant = _running(cfg)
    last = controller.status['u']
    controller.set_manual()
    h = cfg.sample_time
    assert _step(controller, plant, 30.1) == last                 # hold
    controller.set_manual(-0.4)
    for k in range(2, 200):
        assert _step(controller, plant, 30.0 + k * h) == -0.4
        plant.step(np.array([-0.4]), np.array([0.0]), h)
    d = design(cfg).d
    predicted = controller.status['prediction']
    controller.set_auto()
    assert _step(controller, plant, 50.0) == pytest.approx(-0.4, abs=1e-12)
    for _ in range(d - 1):
        plant.step(np.array([-0.4]), np.array([0.0]), h)
    assert plant.outputs()[0] == pytest.approx(predicted, abs=1e-12)


def test_a_non_finite_measurement_holds_the_output_and_recovers_bumplessly():
    cfg = config_of(CASES[0])
    controller, plant = _running(cfg)
    last = controller.status['u']
    assert controller.step(30.1, np.array([math.nan]), np.array([1.0]), np.array([]))[0] == last
    assert controller.status['input_fault'] is True
    assert _step(controller, plant, 30.2) == pytest.approx(last, abs=1e-12)
    assert controller.status['input_fault'] is False


# --------------------------------------------------------------------- refused settings
@pytest.mark.parametrize('values, words', [
    ({'fsa.gain': 0.0}, 'fsa.gain: 0 leaves the process uncontrollable'),
    ({'fsa.omega0': 0.0}, 'fsa.omega0: 0.0 must be > 0'),
    ({'fsa.omega0': 20.0}, r'fsa.omega0: 20 rad/s is too fast for sample_time 0.1 s'),
    ({'fsa.xi': 0.0}, 'fsa.xi: 0 is below the minimum'),
    ({'fsa.model': 'sopdt'}, "fsa.model"),
    ({'fsa.model': 'foupdt', 'fsa.dead_time': 250.0}, r'fsa.dead_time: 250 s is more than 20 '
                                                      r'time constants of the unstable model'),
    ({'fsa.time_constant': 0.0}, 'fsa.time_constant: 0 is below the minimum'),
    ({'u_min': 2.0, 'u_max': 1.0}, 'u_min: 2 must be below u_max 1'),
    ({'fsa.omega0': 'fast'}, "fsa.omega0: 'fast' is a str"),
    ({'fsa.dead_tme': 3.0}, 'fsa.dead_tme: unknown parameter; did you mean fsa.dead_time'),
    ({'manual_output': 5.0, 'u_max': 1.0}, 'manual_output: 5.0 is outside the output limits'),
])
def test_bad_parameters_are_refused_with_a_reason(values, words):
    kind = registry.get_kind('fsa')
    with pytest.raises(ConfigError, match=words):
        registry.settings(kind, values)


# ------------------------------------------------------------------------ as a kind
def test_the_kind_builds_from_parameters_and_changes_live_bumplessly():
    kind = registry.get_kind('fsa')
    values = {'fsa.model': 'foupdt', 'fsa.gain': 1.0, 'fsa.time_constant': 10.0,
              'fsa.dead_time': 5.0, 'fsa.omega0': 0.2, 'fsa.xi': 0.7, 'sample_time': 0.1}
    controller = registry.build(kind, registry.settings(kind, values))
    assert isinstance(controller, FsaController)
    plant = plant_of('foupdt', 1.0, 10.0, 5.0)
    closed_loop(controller, plant, 30.0)
    last_u = controller.status['u']
    y, r, d = plant.outputs(), np.array([1.0]), np.array([])
    # a model change rebuilds: this sample still comes from the old object, bumplessly
    new_settings = registry.settings(kind, {**values, 'fsa.dead_time': 5.5})
    new, u = registry.step_with_changes(kind, controller, new_settings,
                                        frozenset({'fsa.dead_time'}), 30.1, y, r, d)
    assert new is not controller and new.config.dead_time == 5.5
    assert abs(u[0] - last_u) < 0.05
    # a design change is made in place
    faster = registry.settings(kind, {**values, 'fsa.dead_time': 5.5, 'fsa.omega0': 0.25})
    same, _ = registry.step_with_changes(kind, new, faster, frozenset({'fsa.omega0'}),
                                         30.2, y, r, d)
    assert same is new and same.config.omega0 == 0.25


@pytest.mark.parametrize('values, words', [
    ({'fsa.omega0': 1e-300}, r'fsa.omega0: 1e-300 rad/s is too slow for sample_time 0.1 s'),
    ({'fsa.model': 'foupdt', 'fsa.time_constant': 1e-6, 'fsa.dead_time': 0.0},
     r'fsa.time_constant: 1e-06 s is shorter than sample_time 0.1 s'),
])
def test_settings_the_sampled_design_cannot_realise_are_refused(values, words):
    with pytest.raises(ConfigError, match=words):
        registry.settings(registry.get_kind('fsa'), values)
