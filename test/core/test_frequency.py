"""Frequency-domain tools against closed forms ([Checks] §1, §3; [DeadTimeNotes] eq. 6.10–6.13)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.core.analysis import frequency as fr


def p_control(kp: float) -> fr.FrequencyResponse:
    return fr.rational([kp], [1.0])


def i_control(ti: float) -> fr.FrequencyResponse:
    """Pure integral controller 1/(Ti·s) ([DeadTimeNotes] Fig. 6.4)."""
    return fr.rational([1.0], [ti, 0.0])


def delay(dead_time: float) -> fr.FrequencyResponse:
    return fr.rational([1.0], [1.0], dead_time)


# ------------------------------------------------------------ ultimate point
def test_fopdt_ultimate_point_of_spec():
    """[Checks] §1 (checked): K = 0.05, T = 10 s, L = 3 s → Ku = 117.80, Tu = 10.824 s."""
    ku, tu, wu = fr.ultimate_point(fr.fopdt(0.05, 10.0, 3.0))
    assert ku == pytest.approx(117.80, abs=0.005)
    assert tu == pytest.approx(10.824, abs=0.0005)
    assert wu == pytest.approx(2 * math.pi / tu)
    # the defining equations: atan(ωT) + ωL = π and Ku·K/√(1 + ω²T²) = 1
    assert math.atan(wu * 10.0) + wu * 3.0 == pytest.approx(math.pi, abs=1e-10)
    assert ku * 0.05 / math.hypot(1.0, wu * 10.0) == pytest.approx(1.0, rel=1e-10)


@pytest.mark.parametrize('k1,to', [(0.05, 5.0), (2.0, 0.1), (0.001, 120.0)])
def test_ipdt_ultimate_point_closed_form(k1, to):
    """[Checks] §1: ωu = π/(2·To), Ku = π/(2·k1·To), Tu = 4·To."""
    up = fr.ultimate_point(fr.ipdt(k1, to))
    assert up.wu == pytest.approx(math.pi / (2 * to), rel=1e-10)
    assert up.ku == pytest.approx(math.pi / (2 * k1 * to), rel=1e-10)
    assert up.tu == pytest.approx(4 * to, rel=1e-10)


@pytest.mark.parametrize('ratio', [0.01, 0.3, 1.0, 10.0, 100.0])
def test_fopdt_ultimate_point_over_wide_dead_time_range(ratio):
    """Lowest −180° crossing for L/T from 0.01 (lag dominated) to 100 (delay dominated)."""
    t, dead = 10.0, 10.0 * ratio
    up = fr.ultimate_point(fr.fopdt(2.0, t, dead))
    assert math.atan(up.wu * t) + up.wu * dead == pytest.approx(math.pi, abs=1e-9)
    assert up.ku == pytest.approx(math.hypot(1.0, up.wu * t) / 2.0, rel=1e-9)
    # lowest: the bracket [π/(2(T+L))…] — the phase at 0.999·wu is still above −180°
    w = up.wu * 0.999
    assert math.atan(w * t) + w * dead < math.pi


def test_no_ultimate_point_without_dead_time():
    with pytest.raises(ValueError, match='never reaches -180'):
        fr.ultimate_point(fr.fopdt(1.0, 10.0, 0.0))


def test_reverse_acting_plant_ultimate_point_via_negated_response():
    """A negative gain starts the phase at −180°: rejected with a hint; −G gives the
    same |ku| as the positive plant (reverse action = negative kp)."""
    g = fr.fopdt(-0.05, 10.0, 3.0)
    with pytest.raises(ValueError, match='negative gain'):
        fr.ultimate_point(g)
    assert (-1.0 * g).unstable_poles == 0
    assert fr.ultimate_point(-1.0 * g).ku == pytest.approx(117.8033, rel=1e-5)


def test_discrete_ipdt_ultimate_point_closed_form():
    """Sampled IPDT with ZOH, To = d·h: k1·h·z^(−d)/(z − 1) ([DeadTimeNotes] eq. 6.7); its phase
    is −90° − ω·h/2 − ω·To, so ωu = π/(2·(To + h/2)), Ku = 2·sin(ωu·h/2)/(k1·h)."""
    k1, to, h = 0.05, 5.0, 0.5
    up = fr.ultimate_point(fr.ipdt_zoh(k1, to, h))
    wu = math.pi / (2 * (to + h / 2))
    assert up.wu == pytest.approx(wu, rel=1e-9)
    assert up.ku == pytest.approx(2 * math.sin(wu * h / 2) / (k1 * h), rel=1e-9)
    # sampling costs gain: below the continuous π/(2·k1·To)
    assert up.ku < math.pi / (2 * k1 * to)


# ------------------------------------------------------- responses, exact delay
def test_fopdt_response_has_exact_dead_time_phase():
    """|G| unchanged by the dead time, phase lowered by ω·L ([DeadTimeNotes] eq. 6.4) — far
    beyond where a Padé approximation would hold (phase of several turns)."""
    k, t, dead = 0.05, 10.0, 3.0
    w = np.logspace(-3, 2, 400)
    w_, mag, ph = fr.bode(fr.fopdt(k, t, dead), w)
    assert np.allclose(mag, k / np.sqrt(1 + (w * t) ** 2), rtol=1e-12)
    assert np.allclose(ph, np.degrees(-np.arctan(w * t) - w * dead), atol=1e-9)
    assert ph[-1] < -17000.0


def test_ipdt_and_integrators_low_frequency_phase():
    w = np.logspace(-2, 1, 50)
    _, mag, ph = fr.bode(fr.ipdt(0.05, 5.0), w)
    assert np.allclose(mag, 0.05 / w)
    assert np.allclose(ph, -90.0 - np.degrees(5.0 * w))
    # a negative gain with a double integrator starts at −360°; a differentiator at +90°
    _, _, ph2 = fr.bode(fr.rational([-1.0], [1.0, 0.0, 0.0]), w)
    assert np.allclose(ph2, -360.0)
    _, _, ph3 = fr.bode(fr.rational([1.0, 0.0], [0.1, 1.0]), w)
    assert np.allclose(ph3, 90.0 - np.degrees(np.arctan(0.1 * w)))


def test_controller_responses_match_their_formulas():
    s = 1j * np.logspace(-3, 3, 50)
    w = s.imag
    kp, ti, td, n, b, c = 3.134, 18.66, 1.314, 10.0, 0.42, 0.63
    tf = td / n
    c_fb = kp * (1 + 1 / (ti * s) + td * s / (tf * s + 1))
    c_sp = kp * (b + 1 / (ti * s) + c * td * s / (tf * s + 1))
    assert np.allclose(fr.pid_feedback(kp, ti, td, n)(w), c_fb)
    assert np.allclose(fr.pid_setpoint(kp, ti, td, n, b, c)(w), c_sp)
    assert np.allclose(fr.pi(2.0, 4.2)(w), 2.0 * (1 + 1 / (4.2 * s)))
    assert np.allclose(fr.lead(9.5, 0.29, 10)(w), 9.5 * (0.29 * s + 1) / (0.029 * s + 1))
    assert np.allclose(fr.series_pid(5.75, 4.2, 0.29, 10)(w),
                       5.75 * (1 + 1 / (4.2 * s)) * (0.29 * s + 1) / (0.029 * s + 1))
    # td = 0 and ti = inf give P
    assert np.allclose(fr.pid_feedback(2.0)(w), 2.0)


def test_lead_maximum_phase_and_its_frequency():
    """[Ikonen] §1.2: phase lead peaks at ω_max = 1/(td·√α), α = 1/n, at asin((1−α)/(1+α))."""
    td, n = 0.53, 10.0
    w = np.logspace(-1, 3, 20001)
    _, _, ph = fr.bode(fr.lead(1.0, td, n), w)
    i = int(np.argmax(ph))
    assert w[i] == pytest.approx(math.sqrt(n) / td, rel=2e-3)
    assert ph[i] == pytest.approx(math.degrees(math.asin((n - 1) / (n + 1))), abs=1e-4)


# ----------------------------------------------------------------- margins
@pytest.mark.parametrize('dead,ti', [(3.0, 20.0), (1.0, 1.0), (0.5, 10.0), (2.0, 1.5)])
def test_i_control_of_pure_delay(dead, ti):
    """[DeadTimeNotes] eq. 6.11–6.13 ([Checks] §2): ωc = 1/Ti, PM = 90° − L/Ti [rad]. Also by hand:
    −90° − ωL = −180° at ω180 = π/(2L), GM = π·Ti/(2L), delay margin = π·Ti/2 − L."""
    m = fr.margins(i_control(ti) * delay(dead))
    assert m.wc == pytest.approx(1.0 / ti, rel=1e-10)
    assert m.phase_margin == pytest.approx(90.0 - math.degrees(dead / ti), abs=1e-8)
    assert m.w180 == pytest.approx(math.pi / (2 * dead), rel=1e-10)
    assert m.gain_margin == pytest.approx(math.pi * ti / (2 * dead), rel=1e-9)
    assert m.delay_margin == pytest.approx(math.pi * ti / 2 - dead, rel=1e-9)
    # one gain crossover; phase crossovers at −180° − m·360°: ω = (π/2 + 2πm)/L
    assert m.gain_crossovers == pytest.approx((1.0 / ti,))
    k = np.arange(3)
    assert m.phase_crossovers[:3] == pytest.approx(tuple((math.pi / 2 + 2 * math.pi * k) / dead))


def test_i_control_of_pure_delay_stability_boundary():
    """PM > 0 ⇔ L/Ti < π/2 ⇔ closed loop stable ([DeadTimeNotes]: large Ti guarantees stability)."""
    assert fr.closed_loop_stable(i_control(1.0) * delay(1.5))
    assert not fr.closed_loop_stable(i_control(1.0) * delay(1.65))
    m = fr.margins(i_control(1.0) * delay(1.65))
    assert m.phase_margin < 0 and m.gain_margin < 1 and m.delay_margin == 0.0


@pytest.mark.parametrize('kp', [30.0, 60.0, 100.0])
def test_p_control_of_fopdt_margins_by_hand(kp):
    """L = kp·K/(Ts+1)·e^(−Ls): |L| = 1 at ωc = √((kp·K)² − 1)/T,
    PM = 180° − atan(ωc·T) − ωc·L; GM = Ku/kp; delay margin = PM[rad]/ωc."""
    k, t, dead = 0.05, 10.0, 3.0
    m = fr.margins(p_control(kp) * fr.fopdt(k, t, dead))
    wc = math.sqrt((kp * k) ** 2 - 1) / t
    pm = math.pi - math.atan(wc * t) - wc * dead
    assert m.wc == pytest.approx(wc, rel=1e-9)
    assert m.phase_margin == pytest.approx(math.degrees(pm), abs=1e-7)
    assert m.delay_margin == pytest.approx(pm / wc, rel=1e-8)
    assert m.gain_margin == pytest.approx(117.8033 / kp, rel=1e-5)
    assert m.gain_margin_db == pytest.approx(20 * math.log10(117.8033 / kp), abs=1e-4)


def test_delay_margin_is_the_delay_that_zeroes_the_phase_margin():
    loop = fr.pid_feedback(3.0, 18.0, 1.3) * fr.ipdt(0.05, 5.0)
    m = fr.margins(loop)
    assert m.delay_margin > 0
    m2 = fr.margins(loop * delay(m.delay_margin))
    assert m2.phase_margin == pytest.approx(0.0, abs=1e-6)
    assert not fr.closed_loop_stable(loop * delay(1.01 * m.delay_margin))
    assert fr.closed_loop_stable(loop * delay(0.99 * m.delay_margin))


def test_peaks_of_second_order_loop():
    """L = ωn²/(s·(s + 2ζωn)) gives T = ωn²/(s² + 2ζωn·s + ωn²): Mt = 1/(2ζ√(1−ζ²))
    (ζ < 1/√2); Ms checked against a brute-force 10⁶-point evaluation of 1/|1+L|;
    PM closed form: ωc = ωn·√(√(1+4ζ⁴) − 2ζ²), PM = atan(2ζωn/ωc)."""
    zeta, wn = 0.3, 2.0
    loop = fr.rational([wn ** 2], [1.0, 2 * zeta * wn, 0.0])
    m = fr.margins(loop)
    assert m.mt == pytest.approx(1 / (2 * zeta * math.sqrt(1 - zeta ** 2)), rel=1e-8)
    w = np.linspace(0.01, 20.0, 1_000_000)
    s = 1j * w
    brute = np.max(np.abs(s * (s + 2 * zeta * wn) / (s * s + 2 * zeta * wn * s + wn ** 2)))
    assert m.ms == pytest.approx(brute, rel=1e-6)
    assert m.ms >= brute
    wc = wn * math.sqrt(math.sqrt(1 + 4 * zeta ** 4) - 2 * zeta ** 2)
    assert m.wc == pytest.approx(wc, rel=1e-9)
    assert m.phase_margin == pytest.approx(math.degrees(math.atan(2 * zeta * wn / wc)), abs=1e-7)
    assert m.gain_margin == math.inf


def test_ms_is_inverse_distance_to_minus_one():
    loop = fr.pid_feedback(70.68, 5.41, 1.30) * fr.fopdt(0.05, 10.0, 3.0)
    m = fr.margins(loop)
    w = np.linspace(0.3, 1.5, 200_001)
    assert m.ms == pytest.approx(1.0 / np.min(np.abs(1.0 + loop(w))), rel=1e-6)
    assert 0.3 < m.w_ms < 1.5


# ------------------------------------------------------------- Nyquist count
@pytest.mark.parametrize('factor,stable', [(0.98, True), (1.02, False)])
def test_p_control_stable_iff_below_ultimate_gain(factor, stable):
    g = fr.fopdt(0.05, 10.0, 3.0)
    ku = fr.ultimate_point(g).ku
    assert fr.closed_loop_stable(p_control(factor * ku) * g) is stable
    assert fr.closed_loop_poles_unstable(p_control(factor * ku) * g) == (0 if stable else 2)


def test_nyquist_counts_open_loop_unstable_plant():
    """G = 1/(s − 1): P control stabilises for kp > 1 (one encirclement, P = 1)."""
    g = fr.rational([1.0], [1.0, -1.0])
    assert g.unstable_poles == 1
    assert not fr.closed_loop_stable(p_control(0.5) * g)
    assert fr.closed_loop_stable(p_control(2.0) * g)
    # with a dead time L the P-control limit is finite: kp·cos… stable at L = 0.2, kp = 2
    assert fr.closed_loop_stable(p_control(2.0) * g * delay(0.2))
    assert not fr.closed_loop_stable(p_control(2.0) * g * delay(0.7))


# ------------------------------------------------------------- gang of four
def test_gang_of_four_identities():
    g = fr.fopdt(0.05, 10.0, 3.0)
    c = fr.pid_feedback(70.68, 5.41, 1.30)
    w = np.logspace(-3, 1, 300)
    gang = fr.gang_of_four(c, g, w)
    assert np.allclose(gang['S'] + gang['T'], 1.0)
    assert np.allclose(gang['PS'], g(w) * gang['S'])
    assert np.allclose(gang['CS'], c(w) * gang['S'])
    assert np.allclose(gang['S'], fr.sensitivity(c * g, w))
    assert np.allclose(gang['T'], fr.complementary_sensitivity(c * g, w))
    # integral action: S ≈ jω·ti/(kp·K) → 0 as ω → 0 (no static error)
    assert gang['S'][0] == pytest.approx(1j * w[0] * 5.41 / (70.68 * 0.05), rel=1e-2)
    # CS at high frequency → kp·(1 + n) ([Viteckova] eq. 16: the derivative kick), S → 1
    gang_hi = fr.gang_of_four(c, g, np.array([1e4]))
    assert abs(gang_hi['CS'][0]) == pytest.approx(70.68 * 11, rel=1e-2)


# --------------------------------------------------------------- bad input
@pytest.mark.parametrize('call,match', [
    (lambda: fr.fopdt(0.05, -1.0, 3.0), 'time_constant'),
    (lambda: fr.fopdt(0.0, 10.0, 3.0), 'gain'),
    (lambda: fr.ipdt(0.05, -5.0), 'dead_time'),
    (lambda: fr.pid_feedback(1.0, 0.0), 'ti'),
    (lambda: fr.pid_feedback(1.0, 10.0, -1.0), 'td'),
    (lambda: fr.pid_feedback(math.nan), 'kp'),
    (lambda: fr.pid_setpoint(1.0, 10.0, b=1.5), r'b = 1.5.*\[0, 1\]'),
    (lambda: fr.lead(1.0, 0.3, n=0.0), 'n = 0'),
    (lambda: fr.rational([1.0, 0.0, 0.0], [1.0, 1.0]), 'proper'),
    (lambda: fr.rational([], [1.0]), 'num'),
    (lambda: fr.fopdt_zoh(1.0, 10.0, 3.0, 0.0), 'sample_time'),
    (lambda: fr.rational_discrete([1.0], [1.0, -0.5], 1.0, delay_samples=-1), 'delay_samples'),
    (lambda: fr.fopdt_zoh(1.0, 10.0, 3.0, 1.0)(np.array([4.0])), 'Nyquist'),
    (lambda: fr.fopdt_zoh(1.0, 10.0, 3.0, 1.0) * fr.fopdt(1.0, 1.0, 1.0), 'sample_time'),
    (lambda: fr.bode(fr.ipdt(1.0, 1.0), np.array([1.0, 0.5])), 'increasing'),
])
def test_bad_input_rejected_with_reason(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ------------------------------------------------------------ discrete models
def test_rational_discrete_equals_fopdt_zoh_for_whole_sample_delay():
    """[DeadTimeNotes] eq. 6.7: with L = d·h, the ZOH FOPDT is K·(1 − a)·z^(−d)/(z − a), a = e^(−h/T)."""
    k, t, h, d = 0.05, 10.0, 0.5, 6
    a = math.exp(-h / t)
    general = fr.rational_discrete([k * (1 - a)], [1.0, -a], h, delay_samples=d)
    w = np.linspace(0.01, math.pi / h, 40)
    assert np.allclose(general(w), fr.fopdt_zoh(k, t, d * h, h)(w), atol=1e-14)
    assert fr.ultimate_point(general).ku == pytest.approx(fr.ultimate_point(fr.fopdt_zoh(k, t, d * h, h)).ku)


@pytest.mark.parametrize('kp,stable', [(0.4, False), (0.6, True), (2.4, True), (2.6, False)])
def test_discrete_nyquist_count_with_unstable_pole(kp, stable):
    """G = 1/(z − 1.5): the closed-loop pole is 1.5 − kp, inside the unit circle
    for 0.5 < kp < 2.5 (P = 1 open-loop pole outside)."""
    g = fr.rational_discrete([1.0], [1.0, -1.5], 1.0)
    assert g.unstable_poles == 1
    assert fr.closed_loop_stable(p_control_discrete(kp) * g) is stable


def test_discrete_integrator_loop():
    """k·h/(z − 1) (forward-Euler I control of a unit plant): closed-loop pole
    1 − k·h, stable for 0 < k·h < 2; phase starts at −90°; GM = 2/(k·h) at π/h."""
    h, k = 0.1, 5.0
    loop = fr.rational_discrete([k * h], [1.0, -1.0], h)
    assert loop.integrators == 1
    _, _, ph = fr.bode(loop, np.array([1e-4]))
    assert ph[0] == pytest.approx(-90.0, abs=1e-2)
    m = fr.margins(loop)
    assert m.gain_margin == pytest.approx(2.0 / (k * h), rel=1e-6)
    assert m.w180 == pytest.approx(math.pi / h, rel=1e-6)
    assert fr.closed_loop_stable(loop)
    assert not fr.closed_loop_stable(fr.rational_discrete([2.1], [1.0, -1.0], h))
    # the ultimate point of a phase crossing exactly at the Nyquist frequency
    up = fr.ultimate_point(fr.rational_discrete([h], [1.0, -1.0], h))
    assert up.ku == pytest.approx(2.0 / h) and up.tu == pytest.approx(2 * h)


def p_control_discrete(kp: float, h: float = 1.0) -> fr.FrequencyResponse:
    return fr.rational_discrete([kp], [1.0], h)


@pytest.mark.parametrize('k', [1e-3, 0.1, 10.0])
def test_i_control_of_ipdt_is_unstable_for_every_gain(k):
    """k/s · k1/s · e^(−To·s): phase below −180° at every ω > 0, so two closed-loop
    poles in the right half plane for any gain (why [Viteckova] uses PI/PID, not I)."""
    loop = fr.rational([k], [1.0, 0.0]) * fr.ipdt(0.05, 5.0)
    assert fr.closed_loop_poles_unstable(loop) == 2
    assert fr.margins(loop).phase_margin < 0
