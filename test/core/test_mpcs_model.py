"""MPCS prediction model: the document's matrices, closed-form gains, exact delayed prediction."""
from __future__ import annotations

import numpy as np
import pytest

from tank_control.core.control.mpcs_estimator import AugmentedSystem
from tank_control.core.control.mpcs_model import (
    TankOperatingPoint,
    linearize_mixing_tank,
    tank_model,
)
from tank_control.core.control.mpcs_prediction import CostConfig, Prediction


def test_linearization_matches_document_matrices():
    """[Michalski2021] eq. 6 ([Michalski2021] §1): A and B of the tank at the operating point, Ts = 1 s."""
    a, b = linearize_mixing_tank(TankOperatingPoint(), 1.0)
    assert a[0, 0] == pytest.approx(0.99658, abs=1e-5)
    assert a[1, 1] == pytest.approx(0.98638, abs=1e-5)
    assert abs(a[0, 1]) < 1e-12 and abs(a[1, 0]) < 1e-8
    doc_b = np.array([[0.9983, 0.9983, 0.9983, 0, 0, 0],
                      [0.006148, -0.002286, -0.0001233, 0.003028, 0.008001, 0.002595]])
    np.testing.assert_allclose(b, doc_b, rtol=2e-3, atol=2e-7)


def test_steady_state_gains_match_closed_form():
    """h = (ΣF/α)² → dh/dF = 2ΣF/α²; T = ΣF_i T_i / ΣF → dT/dF_H = (T_H − T)/ΣF."""
    op = TankOperatingPoint()
    g = tank_model(op).steady_gain()
    q = op.inflow
    np.testing.assert_allclose(g[0], [2 * q / 49.0] * 2, rtol=1e-9)
    np.testing.assert_allclose(g[1], [(62 - op.T) / q, (23 - op.T) / q], rtol=1e-9)


def test_dead_times_must_be_multiples_of_the_sample_time():
    with pytest.raises(ValueError, match='tau_c'):
        tank_model(TankOperatingPoint(tau_c=180.5), 1.0)


def _simulate(model, sys, xi, bufs, u_prev, d, moves, move_times, steps):
    """Brute-force simulation of the delayed linear model with an input disturbance: states."""
    n = model.n_x
    x = xi[:n].copy()
    w = xi[n:n + sys.n_w]
    lines = [list(b) for b in bufs]
    u = u_prev.copy()
    xs = [x.copy()]
    for j in range(steps):
        for jj, tj in enumerate(move_times):
            if tj == j:
                u = u + moves[jj]
        u_eff = u.copy()
        for i, line in enumerate(lines):
            if line:
                line.append(u[i])
                u_eff[i] = line.pop(0)
        x = model.a @ x + model.b_u @ u_eff + model.b_d @ d + w
        xs.append(x.copy())
    return np.array(xs)


def test_condensed_prediction_equals_step_by_step_simulation():
    """Ŷ = M_z z + G ΔU reproduces a simulation of the delayed model for random data
    (aligned horizon: the p-th prediction of T_out is T(k+p))."""
    model = tank_model(TankOperatingPoint(), 1.0)
    sys = AugmentedSystem(model, 'input')
    cost = CostConfig(horizon=400, control_horizon=60, block=3, terminal_weight=1.0)
    pred = Prediction(sys, cost)
    rng = np.random.default_rng(1)
    xi = rng.normal(size=sys.n)
    bufs = [rng.normal(size=dd) for dd in model.input_delays]
    u_prev, d = rng.normal(size=2), rng.normal(size=2)
    moves = rng.normal(size=(pred.n_moves, 2))
    z = pred.z_vector(xi, bufs, u_prev, d)
    y_hat = pred.m_z @ z + pred.g @ moves.ravel()
    xs = _simulate(model, sys, xi, bufs, u_prev, d, moves, pred.move_times, 400)
    expected = np.stack([xs[1:401, 0], xs[1:401, 1]], axis=1).ravel()
    np.testing.assert_allclose(y_hat, expected, rtol=1e-9, atol=1e-9)
    # the steady-state term: the model settles where the last inputs are held
    y_inf = pred.m_inf @ z + pred.g_inf @ moves.ravel()
    xs_long = _simulate(model, sys, xi, bufs, u_prev, d, moves, pred.move_times, 20000)
    np.testing.assert_allclose(y_inf, xs_long[-1], rtol=1e-6, atol=1e-6)


def test_literal_prediction_reads_the_delay_register():
    """align=False: the p-th T_out prediction is T(k+p−120); for p < 120 that is a past
    model temperature, held in the estimator's register (newest first)."""
    model = tank_model(TankOperatingPoint(), 1.0)
    sys = AugmentedSystem(model, 'input')
    pred = Prediction(sys, CostConfig(horizon=200, control_horizon=20, align=False))
    rng = np.random.default_rng(2)
    xi = rng.normal(size=sys.n)
    bufs = [rng.normal(size=dd) for dd in model.input_delays]
    u_prev, d = rng.normal(size=2), rng.normal(size=2)
    moves = rng.normal(size=(pred.n_moves, 2))
    y_hat = (pred.m_z @ pred.z_vector(xi, bufs, u_prev, d) + pred.g @ moves.ravel())[1::2]
    register = xi[sys.reg_start[1]:sys.reg_start[1] + 120]        # T(k−1), …, T(k−120)
    np.testing.assert_allclose(y_hat[:119], register[118::-1], rtol=1e-12)   # p = 1..119
    xs = _simulate(model, sys, xi, bufs, u_prev, d, moves, pred.move_times, 80)
    np.testing.assert_allclose(y_hat[119:], xs[:81, 1], rtol=1e-9, atol=1e-9)  # p = 120..200


def test_literal_horizon_cannot_see_t_out_and_f_cin():
    """The document's cost with (N, Nu) = (100, 50): no move changes a predicted T_out
    (120 s dead time) and F_Cin changes no predicted output (180 s dead time)."""
    model = tank_model(TankOperatingPoint(), 1.0)
    sys = AugmentedSystem(model, 'input')
    literal = Prediction(sys, CostConfig(horizon=100, control_horizon=50, align=False))
    assert np.all(literal.g[1::2] == 0.0)          # T_out rows
    assert np.all(literal.g[:, 1::2] == 0.0)       # F_Cin columns
    aligned = Prediction(sys, CostConfig(horizon=100, control_horizon=50, align=True))
    assert np.any(aligned.g[1::2, 0::2] != 0.0)    # F_H now moves the predicted T_out
    longer = Prediction(sys, CostConfig(horizon=300, control_horizon=50, align=True))
    assert np.any(longer.g[:, 1::2] != 0.0)        # N > 180: F_Cin visible


def test_model_from_the_plants_linearize_equals_the_own_linearization():
    """tank_model(ab=MixingTank.linearize(ts)) — the plant's (A, B) — gives the same model."""
    from tank_control.core.plants.mixing_tank import MixingTank, MixingTankConfig
    op = TankOperatingPoint(F_H=16.0, F_C=35.0)
    plant = MixingTank(MixingTankConfig(F_H=16.0, F_C=35.0, h_op=op.h, T_op=op.T))
    a, b, c, d = plant.linearize(1.0)
    own = tank_model(op, 1.0)
    other = tank_model(op, 1.0, ab=(a, b))
    np.testing.assert_allclose(other.a, own.a, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(other.b_u, own.b_u, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(other.b_d, own.b_d, rtol=1e-9, atol=1e-12)


def test_estimator_riccati_solution_matches_scipy():
    from scipy.linalg import solve_discrete_are

    from tank_control.core.control.mpcs_estimator import filter_riccati
    model = tank_model(TankOperatingPoint(), 1.0)
    for kind in ('input', 'output'):
        sys = AugmentedSystem(model, kind)
        q = np.zeros(sys.n)
        q[:model.n_x + sys.n_w] = 1e-3
        p = filter_riccati(sys.a, sys.c, np.diag(q), np.eye(2))
        ref = solve_discrete_are(sys.a.T, sys.c.T, np.diag(q), np.eye(2))
        np.testing.assert_allclose(p, ref, rtol=1e-6, atol=1e-8 * np.abs(ref).max())


def test_equilibrium_inputs_reproduce_the_steady_state():
    """The flows found for (h, T) give back h = (ΣF/α)² and T = ΣF_i·T_i/ΣF."""
    from tank_control.core.control.mpcs_model import equilibrium_inputs
    op = TankOperatingPoint(F_D=10.0, T_D=30.0)
    f_h, f_c = equilibrium_inputs(op, 100.0, 38.0)
    q = f_h + f_c + 10.0
    assert (q / 7.0) ** 2 == pytest.approx(100.0)
    assert (f_h * 62 + f_c * 23 + 10.0 * 30) / q == pytest.approx(38.0)
    assert equilibrium_inputs(op, 81.0, 23.5) is None        # colder than reachable


def test_estimate_taken_over_by_a_model_at_another_operating_point():
    """After take_over both models predict the same physical next state and delayed T."""
    from tank_control.core.control.mpcs_estimator import (
        EstimatorConfig,
        KalmanEstimator,
        take_over,
    )
    old_m = tank_model(TankOperatingPoint(), 1.0)
    new_m = tank_model(TankOperatingPoint(F_H=20.0, F_C=30.0, F_D=15.0), 1.0)
    old = KalmanEstimator(old_m, EstimatorConfig())
    new = KalmanEstimator(new_m, EstimatorConfig())
    rng = np.random.default_rng(3)
    old.xi = rng.normal(size=old.sys.n)
    u_eff, d = np.array([16.0, 35.0]), np.array([13.0, 31.0])
    assert take_over(old, new, u_eff, d)
    old.predict(u_eff - old_m.u0, d - old_m.d0)
    new.predict(u_eff - new_m.u0, d - new_m.d0)
    np.testing.assert_allclose(old_m.y0 + old.xi[:2], new_m.y0 + new.xi[:2], atol=1e-9)
    np.testing.assert_allclose(old_m.y0 + old.sys.c @ old.xi, new_m.y0 + new.sys.c @ new.xi,
                               atol=1e-9)
