"""Relay-test identification (core/tuning/identification.py) against closed forms.

References are independent of the code under test: the exact ultimate point is
solved in the helper by bisection of the phase condition ([Checks] §1), the ideal
relay limit cycle of FOPDT has a closed form ([Checks] §1), the plants are exact.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from support.relay import (
    ExactDelayPlant,
    exact_fopdt_ultimate,
    exact_ipdt_ultimate,
    relay_record,
)

from tank_control.core.tuning import identification as ident
from tank_control.core.tuning.model import from_identified

LT_RATIOS = (0.1, 0.3, 1.0, 3.0)


def test_exact_ultimate_point_of_001_example_matches_the_documents():
    ku, tu = exact_fopdt_ultimate(0.05, 10.0, 3.0)
    assert ku == pytest.approx(117.80, abs=0.01)      # [Checks] §1 (checked)
    assert tu == pytest.approx(10.824, abs=0.001)
    model_ku, model_tu = ident.FopdtModel(0.05, 10.0, 3.0).ultimate_point()
    assert (model_ku, model_tu) == pytest.approx((ku, tu), rel=1e-9)
    assert ident.IpdtModel(0.05, 5.0).ultimate_point() == pytest.approx(exact_ipdt_ultimate(0.05, 5.0))


@pytest.mark.parametrize('ratio', LT_RATIOS)
def test_ideal_relay_cycle_period_and_amplitude_match_the_closed_form(ratio):
    """[Checks] §1: a = K·d·(1 − e^(−L/T)), P = 2T·ln(2·e^(L/T) − 1); ku_df = 4d/(πa) ([DeadTimeNotes] eq. 6.22)."""
    gain, tc, d = 2.0, 1.0, 0.5
    period = 2 * tc * math.log(2 * math.exp(ratio) - 1)
    amp = gain * d * (1 - math.exp(-ratio))
    ts = period / 400
    t, u, y = relay_record(ExactDelayPlant(gain, tc, ratio), d, 0.0, 0.0, ts, int(6 * period / ts))
    cycles = ident.relay_cycles(t, u, y, 0.0)[1:]
    assert len(cycles) >= 4
    # a sampled relay switches up to one sample late: the loop sees up to Ts more dead time
    # per switch, which lengthens the period by at most ~4 Ts
    assert np.mean([c.period for c in cycles]) == pytest.approx(period, abs=4 * ts)
    half = np.mean([0.5 * (c.y_max - c.y_min) for c in cycles])
    assert half == pytest.approx(amp, rel=0.01)
    assert ident.ku_describing_function(d, half) == pytest.approx(4 * d / (math.pi * amp), rel=0.01)


def _noisy_relay(case, noise: float, seed: int, samples_per_period: int = 50):
    """Relay on FOPDT (K=1, T=1, L=ratio) or IPDT (k1=0.05, To=5), noise = noise·a, ε = 4σ."""
    d = 1.0
    if case == 'ipdt':
        plant, (ku, tu) = ExactDelayPlant(0.05, None, 5.0), exact_ipdt_ultimate(0.05, 5.0)
        amp = 0.05 * d * 5.0                                  # k1·d·To
    else:
        plant, (ku, tu) = ExactDelayPlant(1.0, 1.0, case), exact_fopdt_ultimate(1.0, 1.0, case)
        amp = d * (1 - math.exp(-case))
    sigma = noise * amp
    eps = 4 * sigma
    ts = tu / samples_per_period
    t, u, y = relay_record(plant, d, eps, sigma, ts, int(6 * tu / ts), seed=seed)
    return t, u, y, eps, ku, tu


@pytest.mark.parametrize('case', LT_RATIOS + ('ipdt',))
@pytest.mark.parametrize('noise', (0.0, 0.01))
def test_first_harmonic_ultimate_point_within_3_and_2_percent(case, noise):
    t, u, y, eps, ku, tu = _noisy_relay(case, noise, seed=7)
    cycles = ident.relay_cycles(t, u, y, 0.0)
    assert len(cycles) >= 5
    res = ident.identify_relay(t, u, y, 0.0, 0.0, eps, cycles=cycles[1:5])
    assert res.cycles == 4
    assert res.ku == pytest.approx(ku, rel=0.03)
    assert res.tu == pytest.approx(tu, rel=0.02)
    assert res.model.kind == ('ipdt' if case == 'ipdt' else 'fopdt')


@pytest.mark.parametrize('case', (0.1, 'ipdt'))
def test_describing_function_is_the_classical_biased_estimate(case):
    """[DeadTimeNotes] eqs. 6.20–6.22: the describing function underestimates Ku by ~18 % at L/T = 0.1
    (IPDT: 8/π² − 1 = −19 %), which is why the first harmonic is used."""
    t, u, y, eps, ku, _ = _noisy_relay(case, 0.0, seed=0, samples_per_period=200)
    res = ident.identify_relay(t, u, y, 0.0, 0.0, eps)
    assert res.ku_df / ku - 1 == pytest.approx(-0.18 if case == 0.1 else 8 / math.pi ** 2 - 1, abs=0.015)


def test_biased_hysteresis_relay_limit_cycle_and_fopdt_from_it():
    """[Precup2013] eqs. 3.3.12–3.3.17: the exact limit cycle, kP from integrals, τ from A_u, T from Tu1."""
    model = ident.FopdtModel(gain=2.0, time_constant=4.0, dead_time=2.0)
    mu, mu0, eps = 1.0, 0.3, 0.1
    cyc = ident.fopdt_relay_limit_cycle(model, mu, mu0, eps)
    ts = 0.002
    t, u, y = relay_record(ExactDelayPlant(2.0, 4.0, 2.0), mu, eps, 0.0, ts, int(120 / ts), bias=mu0)
    cycles = ident.relay_cycles(t, u, y, mu0)[2:]
    assert np.mean([c.y_max for c in cycles]) == pytest.approx(cyc.a_up, rel=2e-3)
    assert -np.mean([c.y_min for c in cycles]) == pytest.approx(cyc.a_down, rel=2e-3)
    assert np.mean([c.high_time for c in cycles]) == pytest.approx(cyc.t_high, abs=2 * ts)
    assert np.mean([c.low_time for c in cycles]) == pytest.approx(cyc.t_low, abs=2 * ts)
    kp = ident.static_gain(t, u, y, cycles[0].start, cycles[-1].end, 0.0, 0.0)
    assert kp == pytest.approx(2.0, rel=5e-3)
    fitted = ident.fopdt_from_biased_relay(mu, mu0, eps, cyc.a_up, cyc.t_high, 2.0)
    assert fitted.time_constant == pytest.approx(4.0, rel=1e-9)
    assert fitted.dead_time == pytest.approx(2.0, rel=1e-9)


def test_static_gain_is_none_for_a_symmetric_relay():
    t, u, y = relay_record(ExactDelayPlant(1.0, 1.0, 1.0), 1.0, 0.0, 0.0, 0.01, 2000)
    cycles = ident.relay_cycles(t, u, y, 0.0)[1:]
    assert ident.static_gain(t, u, y, cycles[0].start, cycles[-1].end, 0.0, 0.0) is None


@pytest.mark.parametrize('order', (1, 2))
def test_model_from_ultimate_point_and_gain_eq_3_6_2(order):
    gain, tc, dead = 1.5, 3.0, 2.0
    # exact ultimate point of K/(Ts+1)^n e^(-Ls), solved here: ωL + n·atan(ωT) = π
    lo, hi = 1e-9, math.pi / dead
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mid * dead + order * math.atan(mid * tc) < math.pi else (lo, mid)
    w = lo
    ku = (1 + (w * tc) ** 2) ** (order / 2) / gain
    fitted = ident.fopdt_from_ultimate(ku, 2 * math.pi / w, gain, order)
    assert fitted.time_constant == pytest.approx(tc, rel=1e-6)
    assert fitted.dead_time == pytest.approx(dead, rel=1e-6)


def test_ipdt_from_ultimate_point_is_exact():
    ku, tu = exact_ipdt_ultimate(0.05, 5.0)
    model = ident.ipdt_from_ultimate(ku, tu)
    assert (model.gain, model.dead_time) == pytest.approx((0.05, 5.0))


@pytest.mark.parametrize('tc', (2.0, None))
def test_sampled_model_response_equals_the_exact_plant_for_fractional_delay(tc):
    rng = np.random.default_rng(3)
    ts, dead = 0.5, 1.3
    u = rng.uniform(-1, 1, 60)
    plant = ExactDelayPlant(0.7, tc, dead)
    ys = []
    for uk in u:
        ys.append(plant.outputs()[0])
        plant.step(np.array([uk]), np.zeros(1), ts)
    sim = ident.simulate_first_order_delay(u, ts, 0.7 / tc if tc else 0.7, 1 / tc if tc else 0.0, dead)
    np.testing.assert_allclose(sim, ys, atol=1e-12)


def test_crossing_times_are_interpolated():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    x = np.array([-1.0, 1.0, 3.0, -1.0])
    assert ident.crossing_times(t, x) == pytest.approx([0.5])
    assert ident.crossing_times(t, x, rising=False) == pytest.approx([2.75])


def test_bad_input_is_rejected_with_a_reason():
    with pytest.raises(ValueError, match='hysteresis'):
        ident.ku_describing_function(1.0, 0.5, hysteresis=0.6)
    with pytest.raises(ValueError, match='non-finite'):
        ident.identify_relay(np.arange(3.0), np.zeros(3), np.array([0, np.nan, 0]), 0.0, 0.0)
    with pytest.raises(ValueError, match='no complete relay cycle'):
        ident.identify_relay(np.arange(3.0), np.ones(3), np.zeros(3), 0.0, 0.0)
    with pytest.raises(ValueError, match='order'):
        ident.fopdt_from_ultimate(2.0, 5.0, 1.0, order=3)
    with pytest.raises(ValueError, match='kind'):
        ident.fit_first_order_delay(1.0, -1 + 0j, kind='sopdt')


@pytest.mark.parametrize('order, alpha', ((2, 1.0), (1, 0.5), (1, 0.0), (3, 2.0)))
def test_local_model_through_two_harmonics_is_exact_for_its_family(order, alpha):
    """k·e^(−Ls)/(s+α)^n through G(jω), G(j3ω) recovers n, α, L, k, and the anchored
    ultimate point equals the one solved from ω·L + n·arctan(ω/α) = π."""
    k, dead, w = 2.0, 0.7, 1.3

    def g(om: float) -> complex:
        return k * np.exp(-1j * om * dead) / (1j * om + alpha) ** order
    m = ident.fit_local_model(w, g(w), g(3 * w))
    if order == 3:
        assert m is None or m.order == pytest.approx(3, rel=1e-6)   # beyond n ≤ 2 at the lag limit
        return
    assert (m.order, m.alpha, m.dead_time, m.gain) == pytest.approx((order, alpha, dead, k), abs=1e-7)
    lo, hi = 1e-9, math.pi / dead
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lag = order * (math.atan2(mid, alpha)) + mid * dead
        lo, hi = (mid, hi) if lag < math.pi else (lo, mid)
    ku, tu = ident.anchored_ultimate_point(m, w, g(w))
    assert ku == pytest.approx(1 / abs(g(lo)), rel=1e-7)
    assert tu == pytest.approx(2 * math.pi / lo, rel=1e-7)


def test_known_static_gain_gives_the_fopdt_by_eq_3_6_2():
    """[DeadTimeNotes] example with kP = 0.05 supplied: T and L from [Precup2013] eq. 3.6.2 through the measured ku, tu."""
    ts = 0.05
    plant = ExactDelayPlant(0.05, 10.0, 3.0)
    amp = 0.05 * 200 * (1 - math.exp(-0.3))
    t, u, y = relay_record(plant, 200.0, 4 * 0.01 * amp, 0.01 * amp, ts, int(70 / ts), seed=4)
    res = ident.identify_relay(t, u, y, 0.0, 0.0, 4 * 0.01 * amp, gain=0.05)
    assert res.model_method == 'eq_3_6_2'
    assert res.model.time_constant == pytest.approx(10.0, rel=0.03)
    assert res.model.dead_time == pytest.approx(3.0, rel=0.03)


@pytest.mark.parametrize('abc_tm', [(2.0, 3.0, 1.0, 1.5), (1.0, 0.6, 1.0, 0.5), (10.0, 7.0, 1.0, 2.0)])
def test_sopdt_from_the_two_points_of_004_eqs_3_5_8_to_3_5_14(abc_tm):
    """[Precup2013] §3.5.2's round trips: the −180° and −90° points of e^(−Tm·s)/(a·s² + b·s
    + c) (found here by bisection on the phase) return (a, b, c, Tm); so do two other points.
    For (2, 3, 1, 1.5) our own round trip ([Checks]) gives ω_b 0.3766, ω_c 0.8981, |H_b| 0.7475, |H_c| 0.3619."""
    a, b, c, tm = abc_tm

    def g(w):
        return np.exp(-1j * w * tm) / (c - a * w * w + 1j * b * w)

    def lag(w):
        return w * tm + math.atan2(b * w, c - a * w * w)
    w_b = brentq(lambda w: lag(w) - math.pi / 2, 1e-9, 10.0)
    w_c = brentq(lambda w: lag(w) - math.pi, w_b, 50.0)
    if abc_tm == (2.0, 3.0, 1.0, 1.5):
        assert (w_b, w_c, abs(g(w_b)), abs(g(w_c))) == pytest.approx(
            (0.3766, 0.8981, 0.7475, 0.3619), abs=6e-5)
    for w1, w2 in ((w_c, w_b), (0.3 * w_b, 1.2 * w_c)):
        m = ident.sopdt_from_two_points(w1, g(w1), w2, g(w2))
        assert (m.a, m.b, m.c, m.dead_time) == pytest.approx((a, b, c, tm), rel=1e-9)
    # eq. 3.5.13 with ω_c in both places (the copy's ω_b fails the round trip)
    assert m.b == pytest.approx(math.sin(w_c * tm) / (w_c * abs(g(w_c))), rel=1e-9)


def test_sopdt_from_two_points_of_a_first_order_process_is_first_order():
    """For an FOPDT, Tm is a double root of [Precup2013] eq. 3.5.10 (both points' linear terms in Tm are
    equal), so 0.2 % error on one point either splits it into two roots — the smaller one trades
    dead time for a small second lag, L + T2 ≈ 3 s — or lifts the touching point off zero, and
    the closest approach gives a ≈ 0, first order (T2 below 0.1 % of T1)."""
    def g(w):
        return 0.05 / (10j * w + 1) * np.exp(-3j * w)
    w_c, w_b = 0.5805, 0.1633
    exact = ident.sopdt_from_two_points(w_c, g(w_c), w_b, g(w_b))
    assert (exact.gain, exact.time_constant, exact.dead_time) == pytest.approx((0.05, 10.0, 3.0), rel=1e-4)
    split = ident.sopdt_from_two_points(w_c, g(w_c) * 0.998, w_b, g(w_b))
    assert 0.05 < split.time_constant2 < 0.2 and split.dead_time < 2.95
    touching = ident.sopdt_from_two_points(w_c, g(w_c) * 1.002, w_b, g(w_b))
    assert touching.time_constant2 < 1e-3 * touching.time_constant
    assert from_identified(touching).kind == 'fopdt'
    for m in (split, touching):
        assert (m.gain, m.time_constant) == pytest.approx((0.05, 10.0), rel=0.01)
        assert m.dead_time + m.time_constant2 == pytest.approx(3.0, rel=0.01)


def test_sopdt_from_two_points_refuses_points_no_lag_fits():
    with pytest.raises(ValueError, match='two different positive frequencies'):
        ident.sopdt_from_two_points(1.0, -0.5 + 0j, 1.0, -0.5 + 0j)
    with pytest.raises(ValueError, match='no dead time fits|not those of a stable'):
        ident.sopdt_from_two_points(1.0, -0.5 + 0j, 0.5, 2.0 + 0j)      # a phase lead
    underdamped = ident.SopdtModel(a=1.0, b=0.6, c=1.0, dead_time=0.5)
    with pytest.raises(ValueError, match='underdamped'):
        from_identified(underdamped)


@pytest.mark.parametrize('method, t_tol', [('tangent', 0.04), ('two_point', 0.01)])
def test_fopdt_from_a_sampled_step_response(method, t_tol):
    """[DeadTimeNotes] eq. 6.15 (tangent of steepest slope) and the 28.3 %/63.2 % two-point method on the
    exact sampled response of [DeadTimeNotes]'s FOPDT (K 0.05, T 10 s, L 3 s) to a step of 200, 80 s at
    0.1 s: K from the last 10 % (e^(−7.7) of the change still to come), T, L; the tangent's
    slope over a window of 1 % of the record is a little below the true K/T at the corner."""
    t = np.arange(0.0, 80.0, 0.1)
    y = 100.0 + np.where(t >= 3.0, 0.05 * 200 * (1 - np.exp(-(t - 3.0) / 10.0)), 0.0)
    m = ident.fopdt_from_step(t, y, 100.0, 200.0, method)
    assert m.gain == pytest.approx(0.05, rel=1e-3)
    assert m.time_constant == pytest.approx(10.0, rel=t_tol)
    assert m.dead_time == pytest.approx(3.0, abs=0.05)
    # a step down: the same model
    down = ident.fopdt_from_step(t, 200.0 - y, 100.0, -200.0, method)
    assert (down.gain, down.time_constant) == pytest.approx((m.gain, m.time_constant))
    res = ident.step_identification(m, 200.0, method)
    assert (res.ku, res.tu) == pytest.approx(m.ultimate_point()) and res.static_gain == m.gain
    with pytest.raises(ValueError, match='did not move'):
        ident.fopdt_from_step(t, np.full_like(t, 100.0), 100.0, 200.0, method)


def test_frequency_points_from_the_relay_transient_of_004_eqs_3_3_1_to_3_3_10():
    """[Precup2013] §3.3 A's check: FOPDT (1, 10 s, 3 s) under an ideal relay ±1 from rest,
    150 s recorded, α = 0.08/s: G(jω) to 3–4 digits at 0.05, 0.2, 0.58 and 1.0 rad/s with the
    pulse response cut at 100 s (≈ 10 T); kept to 200 s, the unweighting e^(α·t) ruins it.
    The hold correction makes 0.1 s sampling as good as 0.01 s."""
    w = np.array([0.05, 0.2, 0.58, 1.0])
    exact = np.exp(-3j * w) / (10j * w + 1)
    for ts in (0.01, 0.1):
        t, u, y = relay_record(ExactDelayPlant(1.0, 10.0, 3.0), 1.0, 0.0, 0.0, ts, int(150 / ts))
        g = ident.transient_response(t, u, y, 0.0, 0.0, w, alpha=0.08, horizon=100.0)
        assert np.max(np.abs(g / exact - 1)) < 1e-3
        ruined = ident.transient_response(t, u, y, 0.0, 0.0, w, alpha=0.08, horizon=200.0)
        assert np.max(np.abs(ruined / exact - 1)) > 0.1
    with pytest.raises(ValueError, match='alpha > 0'):
        ident.transient_response(t, u, y, 0.0, 0.0, w, alpha=0.0, horizon=100.0)


def test_the_lag_window_keeps_the_noise_of_the_transient_points_down():
    """Noise 1 % of the relay output amplitude on the same FOPDT, 146 s from rest, α = 4/73 s,
    cut at L + 7T = 73 s: the division by the relay's ≈ 1/ω spectrum makes the pulse response's
    noise high-frequency, and the unweighting lets it leak into every point — worst of
    0.25…2·ωc off by 6–250 % over six seeds; a Gaussian lag window of Tu/20 (divided out
    exactly) keeps each seed's worst within 8 %."""
    w = 2 * math.pi / 10.82 * np.array([0.25, 0.5, 1.0, 1.5, 2.0])
    exact = np.exp(-3j * w) / (10j * w + 1)
    amp = 1 - math.exp(-0.3)                                   # ideal relay's output amplitude
    bare, windowed = [], []
    for seed in range(6):
        t, u, y = relay_record(ExactDelayPlant(1.0, 10.0, 3.0), 1.0, 0.04 * amp, 0.01 * amp,
                               0.1, 1460, seed=seed)
        for out, smoothing in ((bare, 0.0), (windowed, 10.82 / 20)):
            g = ident.transient_response(t, u, y, 0.0, 0.0, w, alpha=4 / 73, horizon=73.0,
                                         smoothing=smoothing)
            out.append(np.abs(g / exact - 1).max())
    assert max(windowed) < 0.08 and min(bare) > 0.05 and max(bare) > 1.0
    # noise-free, the window costs nothing: its transform at α − jω is divided out
    t, u, y = relay_record(ExactDelayPlant(1.0, 10.0, 3.0), 1.0, 0.0, 0.0, 0.1, 1460)
    g = ident.transient_response(t, u, y, 0.0, 0.0, w, alpha=4 / 73, horizon=73.0,
                                 smoothing=10.82 / 20)
    assert np.abs(g / exact - 1).max() < 2e-3


def test_transient_points_of_an_integrator_from_the_differenced_output():
    """IPDT 0.05/s·e^(−5s) under a relay from rest: its pulse response is a step that never
    dies out, so any cut ruins G (≈ 100 % off); differenced (``integrating``), it ends at the
    dead time and G(jω) = k1·e^(−5jω)/(jω) comes out to 0.05 % cut at 10 s."""
    w = 2 * math.pi / 20 * np.array([0.25, 0.5, 1.0, 1.5, 2.0])
    exact = 0.05 * np.exp(-5j * w) / (1j * w)
    t, u, y = relay_record(ExactDelayPlant(0.05, None, 5.0), 1.0, 0.0, 0.0, 0.1, 860)
    cut = dict(alpha=0.4, horizon=10.0, smoothing=1.0)
    assert np.abs(ident.transient_response(t, u, y, 0.0, 0.0, w, **cut) / exact - 1).min() > 0.9
    g = ident.transient_response(t, u, y, 0.0, 0.0, w, integrating=True, **cut)
    assert np.abs(g / exact - 1).max() < 5e-4
