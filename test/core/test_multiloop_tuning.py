"""[Precup2013] §3.7's equations (eqs. 3.7.4–3.7.10) against hand-computed cases, and the tank's
H_P(jω) against its mass and heat balance."""
from __future__ import annotations

import cmath
import math

import numpy as np
import pytest

from tank_control.core.plants.mixing_tank import MixingTankConfig
from tank_control.core.tuning import multiloop_tuning as mlt


def test_equivalent_processes_eqs_3_7_4_and_3_7_5():
    h = np.array([[2.0, 1.0], [1.0, 3.0]])
    hp1, hp2 = mlt.equivalent_processes(h, 0.5, 1.0)
    assert hp1 == pytest.approx(2.0 - 1.0 * 1.0 * 1.0 / (1.0 + 3.0 * 1.0))    # 1.75
    assert hp2 == pytest.approx(3.0 - 1.0 * 1.0 * 0.5 / (1.0 + 2.0 * 0.5))    # 2.75
    assert mlt.equivalent_processes(h, 0.0, 0.0) == (2.0, 3.0)               # loops open


def test_place_point_pi_and_pid_eqs_3_7_6_and_3_7_7():
    # r_a 0.5 at −180°, loop point 0.5 at −180° − 45°, ω 0.1: kR = cos 45°, Ti = 1/(0.1·tan 45°)
    pi = mlt.place_point(0.5, 0.0, 0.5, math.radians(-45.0), 0.1)
    assert pi.kp == pytest.approx(math.cos(math.radians(45.0)))
    assert pi.ti == pytest.approx(10.0)
    # the loop point is reached: H_P·H_R = r_b·e^{j(−π+φ_b)}
    loop = -0.5 * pi.response(0.1)
    assert abs(loop) == pytest.approx(0.5) and cmath.phase(loop) == pytest.approx(
        math.radians(-225.0) + 2 * math.pi)
    pid = mlt.place_point(0.5, 0.0, 0.5, math.radians(20.0), 0.1, ti_td_ratio=4.0)
    td, ti = pid.kd / pid.kp, pid.ti
    assert ti == pytest.approx(4.0 * td)
    assert 0.1 * td - 1.0 / (0.1 * ti) == pytest.approx(math.tan(math.radians(20.0)))
    with pytest.raises(ValueError, match='PI needs'):
        mlt.place_point(0.5, 0.0, 0.5, 0.1, 0.1)
    neg = mlt.place_point(-0.5, 0.0, 0.5, math.radians(-45.0), 0.1)   # reverse-acting loop
    assert neg.kp == pytest.approx(-pi.kp) and neg.ti == pytest.approx(pi.ti)


def test_zn_point_gives_ziegler_nichols_pi():
    ku, tu = 3.0, 20.0
    g = mlt.place_point(1.0 / ku, 0.0, *mlt.zn_point(), 2.0 * math.pi / tu)
    assert g.kp == pytest.approx(0.45 * ku) and g.ti == pytest.approx(tu / 1.2)


def test_multiloop_design_of_uncoupled_loops_is_siso_zn():
    """e^{−s}/(s + 1) on both loops, no coupling: ω_u solves ω + atan ω = π (2.0288 rad/s),
    Ku = √(1 + ω_u²)."""
    def process(w):
        g = cmath.exp(-1j * w) / (1j * w + 1.0)
        return np.array([[g, 0.0], [0.0, -2.0 * g]])
    d = mlt.multiloop_design(process, *mlt.zn_point(), 1e-3, 10.0, placements=3)
    wu = 2.028757838
    assert d.omega[0] == pytest.approx(wu, rel=1e-6)
    ku = math.sqrt(1.0 + wu * wu)
    assert d.loops[0].kp == pytest.approx(0.45 * ku, rel=1e-6)
    assert d.loops[1].kp == pytest.approx(-0.45 * ku / 2.0, rel=1e-6)      # negative gain
    assert d.loops[1].ti == pytest.approx(2 * math.pi / wu / 1.2, rel=1e-6)


def test_least_squares_recovers_the_exact_mimo_pi_eq_3_7_10():
    """H_P = M/(s + a), target ξ, ω0 with 2ξω0 = a and no dead time: L_w = ω0²/(s(s + a))·I,
    so H_R = ω0²·M⁻¹/s exactly (kp = 0)."""
    m = np.array([[2.0, 1.0], [-1.0, 3.0]])
    xi, w0 = 0.8, 0.5
    a = 2 * xi * w0

    def process(w):
        return m / (1j * w + a)
    omegas = np.geomspace(0.01, 5.0, 30)
    fit = mlt.mimo_pi_least_squares(process, omegas, (w0, w0), (xi, xi), (0.0, 0.0))
    assert fit.residual < 1e-10
    np.testing.assert_allclose(fit.ki, w0 ** 2 * np.linalg.inv(m), atol=1e-9)
    np.testing.assert_allclose(fit.kp, 0.0, atol=1e-9)
    # the two-loop structure D·diag(c) with D = M⁻¹ finds c = ω0²/s on both loops
    dec = mlt.mimo_pi_least_squares(process, omegas, (w0, w0), (xi, xi), (0.0, 0.0),
                                    decoupler=lambda w: np.linalg.inv(m))
    np.testing.assert_allclose(np.diag(dec.ki), [w0 ** 2] * 2, atol=1e-9)
    np.testing.assert_allclose(np.diag(dec.kp), 0.0, atol=1e-9)


def test_tank_static_gains_from_the_balances():
    """h = (F/α)² → ∂h/∂F = 2F/α²; T = ΣF_i·T_i/F → ∂T/∂F_i = (T_i − T)/F ([Michalski2021] §1)."""
    cfg = MixingTankConfig(T_op=2115.0 / 63.0)
    g = mlt.tank_frequency_response(cfg, 1e-9)
    f, t = 63.0, 2115.0 / 63.0
    np.testing.assert_allclose(g.real, [[2 * f / 49.0, 2 * f / 49.0],
                                        [(62.0 - t) / f, (23.0 - t) / f]], rtol=1e-6)
    # the delays: T_out ← F_Cin lags by τ + τ_C = 300 s more than the lags alone
    w = 0.01
    lag = mlt.tank_frequency_response(MixingTankConfig(T_op=t, tau_cold=0.0, tau_out=0.0), w)
    gw = mlt.tank_frequency_response(cfg, w)
    assert cmath.phase(gw[1, 1] / lag[1, 1]) == pytest.approx(-300.0 * w)     # −3 rad
    assert cmath.phase(gw[1, 0] / lag[1, 0]) == pytest.approx(-120.0 * w)
    assert abs(gw[1, 1]) == pytest.approx(abs(lag[1, 1]))


def test_dynamic_decoupler_static_gain_is_2_69():
    assert mlt.d21_filter_response(1e-9, 1.0).real == pytest.approx(2.69, abs=5e-3)
    assert np.allclose(mlt.decoupler_response('none', -1.0, 2.69, 1.0, 0.1), np.eye(2))
