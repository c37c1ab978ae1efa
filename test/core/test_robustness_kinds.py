"""Live robustness (robustness.* and the robustness.ms_max guard) of the lead_lag and smith_pi
kinds: values against an independent dense-grid computation written here from the closed
forms, stability against closed-loop simulations of the core objects."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.control.kinds import lead_lag as ll_kind
from tank_control.core.control.kinds import smith_pi as smith_kind
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.lead_lag import LeadLag, LeadLagConfig
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.smith import SmithModel, SmithPredictor
from tank_control.core.params import ConfigError
from tank_control.core.tuning.model import DiscretePlant, ProcessModel

H = 0.2
K, T, L = 2.0, 5.0, 1.0          # L a multiple of H: the ZOH model below is the textbook one
W = np.linspace(1e-4, math.pi / H, 400_000)
Z = np.exp(1j * W * H)


def zoh_fopdt(k: float, t: float, dead: float) -> np.ndarray:
    """K(1 − a)/(z − a)·z^(−d), a = e^(−h/T), d = L/h (exact ZOH, integer delay)."""
    a = math.exp(-H / t)
    return k * (1 - a) / (Z - a) * Z ** (-round(dead / H))


def lead_lag_c(kp: float, td: float, alpha: float, ti: float) -> np.ndarray:
    z0, p0 = math.exp(-H / td), math.exp(-H / (alpha * td))
    return kp * (1 + H / (ti * (Z - 1))) * (1 - p0) / (1 - z0) * (Z - z0) / (Z - p0)


def simulate_lead_lag(cfg: LeadLagConfig, model: ProcessModel, steps: int = 4000) -> np.ndarray:
    law, plant = LeadLag(cfg), DiscretePlant(model, H)
    y = np.empty(steps)
    for k in range(steps):
        y[k] = plant.output()
        plant.step(law.update(1.0, y[k]))
    return y


LL = {'tuning.model': 'fopdt', 'tuning.gain': K, 'tuning.time_constant': T,
      'tuning.dead_time': L, 'sample_time': H, 'lead_lag.kp': 1.0, 'lead_lag.td': 2.0,
      'lead_lag.alpha': 0.2, 'lead_lag.ti': 6.0}


def test_lead_lag_robustness_is_the_dense_grid_and_the_simulation():
    kind = ll_kind.KIND
    controller = kind.build(resolve(kind, LL))
    res = kind.results(controller)
    loop = lead_lag_c(1.0, 2.0, 0.2, 6.0) * zoh_fopdt(K, T, L)
    assert res['robustness.ms'] == pytest.approx(np.max(np.abs(1 / (1 + loop))), rel=1e-5)
    assert res['robustness.mt'] == pytest.approx(np.max(np.abs(loop / (1 + loop))), rel=1e-5)
    assert res['robustness.stable'] is True and res['robustness.warning'] == ''
    i = np.argmin(np.abs(np.abs(loop) - 1))
    assert res['robustness.crossover'] == pytest.approx(W[i], rel=1e-3)
    assert res['robustness.phase_margin'] == pytest.approx(
        180 + math.degrees(np.angle(loop[i])), abs=0.05)
    model = ProcessModel('fopdt', K, L, T)
    y = simulate_lead_lag(LeadLagConfig(kp=1.0, td=2.0, alpha=0.2, ti=6.0, sample_time=H), model)
    assert abs(y[-200:] - 1.0).max() < 1e-6
    # the gain margin: kp times GM is the stability limit of the simulated loop
    gm = res['robustness.gain_margin']
    for factor, stable in ((0.9, True), (1.1, False)):
        y = simulate_lead_lag(LeadLagConfig(kp=gm * factor, td=2.0, alpha=0.2, ti=6.0,
                                            sample_time=H), model, 8000)
        assert bool(abs(y[-400:] - 1.0).max() < 1e-2) is stable


def test_lead_lag_guard_and_model_update():
    kind = ll_kind.KIND
    bound = {**LL, 'robustness.ms_max': 2.0}
    with pytest.raises(ConfigError, match=r'lead_lag.kp: the loop would be unstable'):
        resolve(kind, {**bound, 'lead_lag.kp': 10.0}, given={'lead_lag.kp'})
    with pytest.raises(ConfigError, match=r'lead_lag.kp: Ms would be 2\.\d+ > robustness.ms_max 2'):
        resolve(kind, {**bound, 'lead_lag.kp': 1.0}, given={'lead_lag.kp'})
    settings = resolve(kind, {**bound, 'lead_lag.kp': 0.5}, given={'lead_lag.kp'})
    controller = kind.build(settings)
    before = kind.results(controller)['robustness.ms']
    worse = resolve(kind, {**bound, 'lead_lag.kp': 0.5, 'tuning.dead_time': 2.0},
                    given={'tuning.dead_time'})           # a model change is not refused
    kind.update(controller, worse, frozenset({'tuning.dead_time'}))
    after = kind.results(controller)
    loop = lead_lag_c(0.5, 2.0, 0.2, 6.0) * zoh_fopdt(K, T, 2.0)
    assert after['robustness.ms'] == pytest.approx(np.max(np.abs(1 / (1 + loop))), rel=1e-5)
    assert after['robustness.ms'] > before
    assert after['robustness.model'] == 'fopdt K=2 T=5 s L=2 s'


SM = {'smith.model': 'fopdt', 'smith.gain': K, 'smith.time_constant': T, 'smith.dead_time': L,
      'sample_time': H, 'kp': 2.0, 'ti': 5.0}


def smith_s(kp: float, ti: float, k: float = K, dead: float = L) -> np.ndarray:
    """S = (1 + C·(Gm0 − Gm))/(1 + C·Gm0) of the Smith loop on its own model."""
    c = kp * (1 + H / (ti * (Z - 1)))
    g0, g = zoh_fopdt(k, T, 0.0), zoh_fopdt(k, T, dead)
    return (1 + c * (g0 - g)) / (1 + c * g0)


def simulate_smith(kp: float, ti: float, steps: int = 3000) -> np.ndarray:
    ctrl = SmithPredictor(SmithModel('fopdt', K, T, L), PidConfig(kp=kp, ti=ti, sample_time=H))
    plant = DiscretePlant(ProcessModel('fopdt', K, L, T), H)
    ctrl.reset(np.array([0.0]), np.array([0.0]))
    y = np.empty(steps)
    for k in range(steps):
        y[k] = plant.output()
        plant.step(float(ctrl.step(k * H, np.array([y[k]]), np.array([1.0]), np.array([]))[0]))
    return y


def test_smith_robustness_is_the_dense_grid_and_the_simulation():
    kind = smith_kind.KIND
    res = kind.results(kind.build(resolve(kind, SM)))
    s = smith_s(2.0, 5.0)
    assert res['robustness.ms'] == pytest.approx(np.max(np.abs(s)), rel=1e-5)
    assert res['robustness.mt'] == pytest.approx(np.max(np.abs(1 - s)), rel=1e-5)
    assert res['robustness.stable'] is True
    assert abs(simulate_smith(2.0, 5.0)[-200:] - 1.0).max() < 1e-6
    # the delay-free loop K(1 − a)·kp/(z − a) (ti large) is unstable for kp·K(1 − a) > 1 + a
    a = math.exp(-H / T)
    kp_limit = (1 + a) / (K * (1 - a))
    # a predictor unstable on its own model is refused, no robustness bound needed
    with pytest.raises(ConfigError, match='the Smith loop would be unstable'):
        resolve(kind, {**SM, 'kp': 1.2 * kp_limit, 'ti': 1e6})
    assert abs(simulate_smith(1.2 * kp_limit, 1e6)[-50:]).max() > 1e3
    resolve(kind, {**SM, 'kp': 0.95 * kp_limit, 'ti': 1e6})      # just stable: runs


def test_smith_guard_and_model_update():
    kind = smith_kind.KIND
    bound = {**SM, 'robustness.ms_max': 1.5}
    with pytest.raises(ConfigError, match=r'kp: Ms would be 1\.\d+ > robustness.ms_max 1.5'):
        resolve(kind, {**bound, 'kp': 3.0}, given={'kp'})
    with pytest.raises(ConfigError, match='the Smith loop would be unstable'):
        resolve(kind, {**bound, 'kp': 60.0}, given={'kp'})
    controller = kind.build(resolve(kind, {**bound, 'kp': 1.0}, given={'kp'}))
    assert kind.results(controller)['robustness.ms'] == pytest.approx(
        np.max(np.abs(smith_s(1.0, 5.0))), rel=1e-5)
    changed = resolve(kind, {**bound, 'kp': 1.0, 'smith.dead_time': 3.0},
                      given={'smith.dead_time'})
    if not kind.update(controller, changed, frozenset({'smith.dead_time'})):
        controller = kind.build(changed)                      # a model change rebuilds
    res = kind.results(controller)
    assert res['robustness.model'] == 'fopdt K=2 T=5 s L=3 s'
    assert res['robustness.ms'] == pytest.approx(np.max(np.abs(smith_s(1.0, 5.0, dead=3.0))),
                                                 rel=1e-5)
