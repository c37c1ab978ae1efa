"""Margins of [Michalski2021]'s two-loop PI on the linearised tank with its delays (core/analysis/two_loop.py):
why the decoupled loop of [Michalski2021] §3 is lightly damped on our tank (docs/scenarios.md, "[Michalski2021]").
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.analysis.two_loop import LinearisedTank, document_analysis
from tank_control.core.control.multiloop import D21Filter, document_config
from tank_control.core.plants.mixing_tank import OPERATING_POINT as OP


def test_linearised_tank_has_the_static_gains_and_delays_of_003_s_balances():
    """Independently of the Jacobian: F = α·√h gives dh/dF = 2·√h/α; the mixing balance
    gives dT/dF_i = (T_i − T)/F_in; F_Cin acts τ_C later, T_out shows T τ later."""
    plant = LinearisedTank.from_config()
    g0 = plant.at(np.array([1e-12j]))[0].real
    assert g0[0, 0] == pytest.approx(2 * math.sqrt(OP.h) / OP.alpha, rel=1e-6)
    assert g0[0, 1] == pytest.approx(g0[0, 0], rel=1e-9)
    assert g0[1, 0] == pytest.approx((OP.T_H - OP.T) / OP.inflow, rel=1e-6)
    assert g0[1, 1] == pytest.approx((OP.T_C - OP.T) / OP.inflow, rel=1e-6)
    w = 0.004
    g = plant.at(np.array([1j * w]))[0]
    assert np.angle(g[0, 1] / g[0, 0]) == pytest.approx(-w * OP.tau_c)
    assert np.angle(g[1, 0] * (1j * w + OP.inflow / OP.V)) == pytest.approx(-w * OP.tau)
    assert np.angle(-g[1, 1] / g[1, 0]) == pytest.approx(-w * OP.tau_c)


def test_the_decoupler_of_003_cancels_the_interaction_only_at_steady_state():
    """D12 = −1, D21 = 2.69 (eq. 2's filter has its pole on its zero: its static gain) zero
    the off-diagonal of G·W at s = 0; with τ_C = 180 s, v_T still moves the level by
    (e^(−τ_C·s) − 1)·h/F_H, twice the direct effect at ω = π/τ_C."""
    analysis = document_analysis('dynamic')
    q0 = analysis.decoupled_plant(np.array([1e-12j]))[0]
    g0 = analysis.plant.at(np.array([1e-12j]))[0]
    assert abs(q0[0, 1]) < 1e-9 * abs(g0[0, 0])
    assert abs(q0[1, 0]) < 1e-3 * abs(g0[1, 0])           # 2.69 vs (T_H − T)/(T − T_C) = 2.6892
    w = math.pi / OP.tau_c
    point = np.array([1j * w])
    q, g = analysis.decoupled_plant(point)[0], analysis.plant.at(point)[0]
    assert abs(q[0, 1]) == pytest.approx(2 * abs(g[0, 0]))
    z = np.exp(1j * np.linspace(1e-3, math.pi, 50))                   # eq. 2 on the unit circle
    d21 = (0.00619 * z + 2.122e-5) / (0.002301 * z + 7.897e-6)
    assert np.max(np.abs(d21 / D21Filter.dc_gain() - 1)) < 1e-5


def test_document_decoupled_gains_are_lightly_damped_only_because_of_the_delays():
    """The central measured fact: [Michalski2021] §3.1's gains (level 0.04/0.0004, T 0/−0.01) with the
    decoupler, on the tank with τ_C = 180 s and τ = 120 s, give the T loop a phase margin
    below 20° and Ms above 4 (the level loop closed), the level loop Ms above 2; the same
    gains with the delays removed give both loops PM above 60° and Ms below 1.3 — the well
    damped loop [Michalski2021] §3.5 describes. [Michalski2021] §2.1's gains without decoupling keep PM above 60°
    with the delays."""
    with_delays = document_analysis('dynamic').report()
    assert with_delays['T_out|h closed']['phase_margin'] < 20.0
    assert with_delays['T_out|h closed']['ms'] > 4.0
    assert with_delays['h|T_out closed']['ms'] > 2.0
    assert with_delays['h|T_out closed']['phase_margin'] < 45.0
    delay_free = document_analysis('dynamic', tau_cold=0.0, tau_out=0.0).report()
    plain = document_analysis('none').report()
    for report, ms in ((delay_free, 1.3), (plain, 1.5)):
        for loop in ('h|T_out closed', 'T_out|h closed'):
            assert report[loop]['phase_margin'] > 60.0
            assert report[loop]['ms'] < ms


def test_d12_makes_the_temperature_loop_aggressive_d21_delays_the_level_loop():
    """Each decoupler term alone (the other loop open): with D12 = −1 the T loop's process
    is −(b_H·e^(−τ·s) + |b_C|·e^(−(τ+τ_C)·s))/(s + a_T), 3.69 times the F_Cin path's static
    gain and 73 % of it 180 s sooner (through F_H): its PM falls from 54° to 19°; with
    D21 = 2.69 the level loop's process is (1 + 2.69·e^(−τ_C·s))·h/F_H, 73 % of its gain
    τ_C late: its PM falls from 80° to 44°."""
    none = document_analysis('static', d12=0.0, d21=0.0).report()   # decoupled gains, W = I
    d12 = document_analysis('static', d21=0.0).report()
    d21 = document_analysis('static', d12=0.0).report()
    assert none['T_out']['phase_margin'] - d12['T_out']['phase_margin'] > 30.0
    assert d12['T_out']['phase_margin'] < 20.0
    assert d12['h']['phase_margin'] == pytest.approx(none['h']['phase_margin'])
    assert none['h']['phase_margin'] - d21['h']['phase_margin'] > 30.0
    assert d21['T_out']['phase_margin'] == pytest.approx(none['T_out']['phase_margin'])


def test_lower_gains_restore_the_margins_with_the_delays():
    """Level gains halved (0.02/0.0002) and ki_T = −0.002 ([Michalski2021] §2.1's T integral gain): both
    loops Ms < 1.45 with the other closed, on the tank with its delays."""
    report = document_analysis('dynamic', kp_h=0.02, ki_h=0.0002, ki_T=-0.002).report()
    for loop in ('h|T_out closed', 'T_out|h closed'):
        assert report[loop]['ms'] < 1.45
        assert report[loop]['phase_margin'] > 55.0


def test_stability_of_the_analysis_agrees_with_the_linearised_plant():
    """The Nyquist count of the analysis against a simulation of the linearised tank
    (core LinearTank + TwoLoopPi, a 0.5 cm level step): [Michalski2021] §2.1's gains with the decoupler
    are predicted unstable and their oscillation grows; [Michalski2021] §3.1's are predicted stable and
    theirs decays."""
    from tank_control.core.control.multiloop import TwoLoopPi
    from tank_control.core.plants.linear_tank import LinearTank

    def swing(cfg) -> tuple[float, float]:
        plant, ctrl = LinearTank(), TwoLoopPi(cfg)
        ctrl.reset(plant.outputs(), plant.nominal_inputs())
        r = np.array([OP.h + 0.5, OP.T])
        h = []
        for k in range(12000):
            u = ctrl.step(float(k), plant.outputs(), r, np.array([]))
            plant.step(u, [], 1.0)
            h.append(plant.outputs()[0])
        h = np.abs(np.array(h) - r[0])
        return float(h[2000:4000].max()), float(h[10000:].max())

    from tank_control.core.analysis import frequency as fr

    unstable = document_config('dynamic', kp_h=0.9, ki_h=0.01, kp_T=-0.2, ki_T=-0.002)
    predicted = document_analysis('dynamic', kp_h=0.9, ki_h=0.01, kp_T=-0.2, ki_T=-0.002)
    assert not predicted.stable()
    # the same closed-loop poles counted from either loop's equivalent process (eq. 3.7.4/5)
    assert fr.closed_loop_poles_unstable(predicted.loop(0)) == \
        fr.closed_loop_poles_unstable(predicted.loop(1)) > 0
    early, late = swing(unstable)
    assert late > early
    assert document_analysis('dynamic').stable()
    early, late = swing(document_config('dynamic'))
    assert late < 0.1 * early
