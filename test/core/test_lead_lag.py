"""The lead-lag compensator (core/control/lead_lag.py): its discrete transfer function sample
by sample, the choice of discretisation, and [Ikonen]'s worked example ([Checks] §5) —
the design procedure's numbers, the documents' margins, Ms values and step responses."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from tank_control.core.analysis import frequency as fr
from tank_control.core.control.lead_lag import (LeadLag, LeadLagConfig, LeadLagTuning,
                                                continuous_response, design,
                                                discrete_polynomials, discrete_response)

ALPHA = 0.1                                   # [Ikonen]: derivative filter ten times faster
PLANT_002 = fr.rational([4.0], [1.0, 3.0, 2.0])   # [Ikonen]'s process ([Checks] §5)
TUNING_002 = dict(rule='frequency_002', model='sopdt', gain=2.0, time_constant=1.0,
                  time_constant2=0.5)


def design_002(kind: str, **targets):
    return design(LeadLagTuning(kind=kind, **TUNING_002, **targets), ALPHA)


def td_for(w_max: float, alpha: float = ALPHA) -> float:
    """[Ikonen] §1.2: the lead's largest phase sits at w_max = 1/(td·√alpha)."""
    return 1.0 / (w_max * math.sqrt(alpha))


# ------------------------------------------------------- the implemented transfer function
def expected_polynomials(kp, td, alpha, ti, h):
    """C(z) written out here from its derivation: the lead's zero −1/td and pole
    −1/(alpha·td) mapped by z = e^(sh), unit gain at z = 1; the PI by forward Euler."""
    num, den = np.poly1d([kp]), np.poly1d([1.0])
    if td > 0:
        z0, p0 = math.exp(-h / td), math.exp(-h / (alpha * td))
        num *= np.poly1d([1.0, -z0]) * ((1 - p0) / (1 - z0))
        den *= np.poly1d([1.0, -p0])
    if math.isfinite(ti):
        num *= np.poly1d([1.0, -1.0 + h / ti])        # 1 + h/(ti(z − 1)) = (z − 1 + h/ti)/(z − 1)
        den *= np.poly1d([1.0, -1.0])
    return num.coeffs, den.coeffs


CASES = [(2.3, 0.7, 0.15, 3.1), (9.5, 0.2944, 0.1, math.inf), (1.8, 0.0, 0.1, 4.47),
         (5.0, 0.0, 0.5, math.inf)]


@pytest.mark.parametrize('h', [0.001, 0.05, 1.0, 100.0])
@pytest.mark.parametrize('kp,td,alpha,ti', CASES, ids=['lead_pi', 'lead', 'pi', 'p'])
def test_implementation_is_its_transfer_function_sample_by_sample(kp, td, alpha, ti, h):
    """Random setpoint and measurement sequences through LeadLag (from rest) equal the
    difference equation of C(z) (scipy lfilter, zero initial state) at every sample, for
    sample times from far below to far above the lead's time constants."""
    rng = np.random.default_rng(7)
    r, y = rng.normal(size=400), rng.normal(size=400)
    law = LeadLag(LeadLagConfig(kp=kp, td=td, alpha=alpha, ti=ti, sample_time=h,
                                anti_windup='none'))
    law.reset(0.0, 0.0, 0.0)
    u = np.array([law.update(a, b) for a, b in zip(r, y)])
    num, den = expected_polynomials(kp, td, alpha, ti, h)
    expected = signal.lfilter(num / den[0], den / den[0], r - y)
    assert np.allclose(u, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    # ... and the module's polynomials / frequency response are that transfer function
    got_num, got_den = discrete_polynomials(kp, td, alpha, ti, h)
    w = np.linspace(0.01, math.pi / h, 40)
    z = np.exp(1j * w * h)
    ours = discrete_response(kp, td, alpha, ti, h)(w)
    assert np.allclose(ours, np.polyval(num, z) / np.polyval(den, z), rtol=1e-9)
    assert np.allclose(np.polyval(got_num, z) / np.polyval(got_den, z), ours, rtol=1e-9)


@pytest.mark.parametrize('h', [1e-6, 1e-3, 0.1, 10.0, 1e3, 1e6])
def test_lead_is_stable_without_ringing_and_exact_at_low_frequency_for_any_sample_time(h):
    """Pole of the discrete lead in (0, 1) for every h (no alternating impulse response),
    gain exactly 1 at z = 1, high-frequency gain between 1 and 1/alpha."""
    kp, td, alpha = 1.0, 0.5, 0.1
    num, den = discrete_polynomials(kp, td, alpha, math.inf, h)
    pole = np.roots(den)
    assert pole.size == 1 and 0.0 <= pole[0].real < 1.0 and pole[0].imag == 0.0
    assert np.polyval(num, 1.0) / np.polyval(den, 1.0) == pytest.approx(1.0, rel=1e-9)
    nyquist = abs(np.polyval(num, -1.0) / np.polyval(den, -1.0))
    assert 1.0 - 1e-12 <= nyquist <= 1.0 / alpha + 1e-9


def test_discrete_law_tends_to_the_continuous_series_pid():
    """As h → 0 C(e^(jωh)) → [Ikonen]'s series PID kp·(1 + 1/(ti s))·(td s + 1)/(alpha td s + 1)
    of core/analysis/frequency.py (written independently) on 0.01…100 rad/s."""
    kp, td, ti = 5.75, td_for(10.8), 4.2
    w = np.logspace(-2, 2, 30)
    cont = fr.series_pid(kp, ti, td, n=1 / ALPHA)(w)
    assert np.allclose(continuous_response(kp, td, ALPHA, ti)(w), cont, rtol=1e-12)
    for h, tolerance in ((1e-2, 0.05), (1e-3, 1e-3), (1e-4, 1e-4)):
        disc = discrete_response(kp, td, ALPHA, ti, h)(w)
        assert np.max(np.abs(disc / cont - 1)) < tolerance, h


def zoh_002(h: float) -> fr.FrequencyResponse:
    """Exact step-invariant model of [Ikonen]'s process (scipy's ZOH discretisation)."""
    num, den, _ = signal.cont2discrete(([4.0], [1.0, 3.0, 2.0]), h, 'zoh')
    with np.errstate(invalid='ignore'):      # its sampling zero is negative: log(<0) for a corner
        return fr.rational_discrete(np.ravel(num), den, h)


@pytest.mark.parametrize('h', [0.005, 0.01, 0.02])
def test_matched_lead_costs_hardly_more_than_the_hold(h):
    """Why matched pole-zero for the lead: on the sampled [Ikonen] PD loop (exact ZOH plant) its
    phase margin stays within a fifth of the hold's half-sample loss ω_c·h/2 of the
    continuous design with h/2 of dead time added, while the backward difference (the
    PID's derivative filter) loses about another ω_c·h/2."""
    kp, td = 9.5, design_002('pd').td
    lagged = fr.margins(continuous_response(kp, td, ALPHA) * fr.rational([4.0], [1, 3, 2], h / 2))
    half_sample = math.degrees(lagged.wc * h / 2)
    with np.errstate(invalid='ignore'):
        matched = fr.margins(discrete_response(kp, td, ALPHA, math.inf, h) * zoh_002(h))
        backward = fr.margins(fr.rational_discrete(
            kp * np.array([td + h, -td]), [ALPHA * td + h, -ALPHA * td], h) * zoh_002(h))
    assert abs(matched.phase_margin - lagged.phase_margin) < 0.2 * half_sample
    assert lagged.phase_margin - backward.phase_margin > 0.6 * half_sample


# ------------------------------------------------------------------- [Ikonen]'s design steps
def test_002_p_gain_and_its_loop():
    """[Ikonen] §1.1: 1/(1 + 2·kp) = 5 % → kp = 9.5; Fig. 2 "Pm = 28.(1) deg (at 5.96 rad/s)".
    The crossover in closed form: 38² = (ω² + 1)(ω² + 4)."""
    d = design_002('p')
    assert d.kp == pytest.approx(9.5, rel=1e-12)
    wc = math.sqrt((-5 + math.sqrt(25 + 4 * (38 ** 2 - 4))) / 2)
    pm = 180 - math.degrees(math.atan(wc) + math.atan(wc / 2))
    assert (d.wc, d.phase_margin) == pytest.approx((wc, pm), rel=1e-9)
    assert round(pm, 1) == 28.1 and round(wc, 2) == 5.96
    assert (d.td, d.ti) == (0.0, math.inf)


def test_002_lead_iteration_reproduces_figs_4_and_6():
    """[Ikonen] §1.2: w_max at the P crossover (Fig. 4), then the mean of it and the new crossover
    (Fig. 6, PM "already 70°": stop). The margins are checked with frequency.py."""
    d = design_002('pd')
    wc_p = math.sqrt((-5 + math.sqrt(25 + 4 * (38 ** 2 - 4))) / 2)
    first = fr.margins(fr.lead(9.5, td_for(wc_p), 1 / ALPHA) * PLANT_002)
    second_w = (wc_p + first.wc) / 2
    second = fr.margins(fr.lead(9.5, td_for(second_w), 1 / ALPHA) * PLANT_002)
    steps = d.lead_steps
    assert len(steps) == 2
    assert steps[0].w_max == pytest.approx(wc_p, rel=1e-9)
    assert (steps[0].phase_margin, steps[0].wc) == pytest.approx(
        (first.phase_margin, first.wc), rel=1e-6)
    assert steps[1].w_max == pytest.approx(second_w, rel=1e-6)
    assert (d.kp, d.td, d.ti) == pytest.approx((9.5, td_for(second_w), math.inf), rel=1e-6)
    assert (d.phase_margin, d.wc) == pytest.approx((second.phase_margin, second.wc), rel=1e-6)
    # Fig. 6: "Pm = 70.5 deg (at 10.9 rad/s)", T_D "0.29" s: reproduced to the printed digits
    assert round(d.phase_margin, 1) == 70.5 and round(d.wc, 1) == 10.9 and round(d.td, 2) == 0.29
    # Fig. 4 prints 54.9 deg at 15.5 rad/s, T_D 0.53 s; the exact crossover 5.961 gives
    # T_D 0.5305 and 54.64 deg at 15.52. The document read 6 rad/s off its Bode plot: with
    # w_max = 6 the margin is its 54.9 deg at 15.5 rad/s (T_D 0.527).
    assert round(first.phase_margin, 2) == 54.64 and round(first.wc, 2) == 15.52
    read_off = fr.margins(fr.lead(9.5, td_for(6.0), 1 / ALPHA) * PLANT_002)
    assert round(read_off.phase_margin, 1) == 54.9 and round(read_off.wc, 1) == 15.5
    # the iterated w_max: (5.961 + 15.518)/2 = 10.74, the document's (6 + 15.5)/2 "10.8"
    assert round(second_w, 1) == 10.7


def test_002_pi_doc_numbers_and_our_design():
    """[Ikonen] §1.3: kp = 2 (Fig. 8 "Pm = 62.9 deg (at 2.37 rad/s)"), Ti = 10/2.4 = 4.2 s
    (Fig. 10 "Pm = 57.(1) deg (at 2.38 rad/s)", "still nearly 60"). The document picked
    kp = 2 off the plot; the integral then costs 5.9 deg. Our design solves for the target:
    the PI loop's margin is exactly 60 deg with Ti = 10/(the P loop's crossover)."""
    p_loop = fr.margins(2.0 * PLANT_002)
    assert round(p_loop.phase_margin, 1) == 62.9 and round(p_loop.wc, 2) == 2.37
    doc = fr.margins(continuous_response(2.0, 0.0, ALPHA, 4.2) * PLANT_002)
    assert round(doc.phase_margin, 1) == 57.1 and round(doc.wc, 2) == 2.38
    assert round(p_loop.phase_margin - doc.phase_margin, 1) == 5.9
    d = design_002('pi')
    ours = fr.margins(fr.pi(d.kp, d.ti) * PLANT_002)
    assert ours.phase_margin == pytest.approx(60.0, abs=1e-6)
    assert d.ti == pytest.approx(10.0 / fr.margins(d.kp * PLANT_002).wc, rel=1e-9)
    assert d.td == 0.0 and 1.5 < d.kp < 2.0        # lower than the document's 2: the 60 deg


def test_002_series_pid():
    """[Ikonen] §1.4: PID = PD·PI, gain the mean of the two; the document's (9.5 + 2)/2 = 5.75,
    T_D 0.29, Ti 4.2 s: "crossover 7 rad/s, phase margin 75°" (Fig. 17)."""
    doc = fr.margins(fr.series_pid(5.75, 4.2, td_for(10.8), 1 / ALPHA) * PLANT_002)
    assert round(doc.phase_margin) == 75 and round(doc.wc) == 7
    pd, pi, d = design_002('pd'), design_002('pi'), design_002('pid')
    assert (d.kp, d.td, d.ti) == pytest.approx(((pd.kp + pi.kp) / 2, pd.td, pi.ti), rel=1e-12)
    ours = fr.margins(continuous_response(d.kp, d.td, ALPHA, d.ti) * PLANT_002)
    assert (d.phase_margin, d.wc) == pytest.approx((ours.phase_margin, ours.wc), rel=1e-6)
    assert round(ours.phase_margin) == 75 and round(ours.wc) == 7
    assert fr.closed_loop_stable(continuous_response(d.kp, d.td, ALPHA, d.ti) * PLANT_002)


def test_002_gang_of_four_ms_and_high_frequency_gain():
    """[Ikonen] Figs. 14–16: Ms of the document's designs PI 1.44, PD 1.20, PID 1.14 (PI weakest);
    the same order for ours. C(∞) = kp/alpha: 95 (PD), 57.5 (PID) — the implemented law's
    output step after a unit setpoint step tends to it as h → 0."""
    doc = {'PD': (9.5, td_for(10.8), math.inf), 'PI': (2.0, 0.0, 4.2),
           'PID': (5.75, td_for(10.8), 4.2)}
    ms = {k: fr.margins(continuous_response(kp, td, ALPHA, ti) * PLANT_002).ms
          for k, (kp, td, ti) in doc.items()}
    assert {k: round(v, 2) for k, v in ms.items()} == {'PD': 1.20, 'PI': 1.44, 'PID': 1.14}
    ours = {k: design_002(k.lower()) for k in doc}
    ms_ours = {k: fr.margins(continuous_response(d.kp, d.td, ALPHA, d.ti) * PLANT_002).ms
               for k, d in ours.items()}
    assert ms_ours['PI'] > ms_ours['PD'] > ms_ours['PID']
    for name, kick in (('PD', 95.0), ('PID', 57.5)):
        kp, td, ti = doc[name]
        law = LeadLag(LeadLagConfig(kp=kp, td=td, alpha=ALPHA, ti=ti, sample_time=0.001))
        law.reset(0.0, 0.0, 0.0)
        law.update(0.0, 0.0)
        assert law.update(1.0, 0.0) == pytest.approx(kick, rel=0.02)


# ------------------------------------------------------------------ step responses
def simulate_002(kp, td, ti, h=0.001, t_end=12.0, r=1.0, u_min=-1e9, u_max=1e9,
                 anti_windup='back_calculation'):
    """Setpoint step on [Ikonen]'s process at rest (exact ZOH state-space model of scipy),
    the implemented LeadLag in the loop; returns (t, y, u)."""
    a, b, c, dd = signal.tf2ss([4.0], [1.0, 3.0, 2.0])
    ad, bd, cd, _, _ = signal.cont2discrete((a, b, c, dd), h, 'zoh')
    law = LeadLag(LeadLagConfig(kp=kp, td=td, alpha=ALPHA, ti=ti, sample_time=h, u_min=u_min,
                                u_max=u_max, anti_windup=anti_windup))
    law.reset(0.0, 0.0, 0.0)
    x = np.zeros((2, 1))
    ys, us = [], []
    for _ in range(int(round(t_end / h))):
        y = float((cd @ x)[0, 0])
        u = law.update(r, y)
        x = ad @ x + bd * u
        ys.append(y)
        us.append(u)
    return np.arange(len(ys)) * h, np.array(ys), np.array(us)


def settled_after(t, y, final, band):
    outside = np.flatnonzero(np.abs(y - final) > band * abs(final))
    return t[outside[-1] + 1] if outside.size else 0.0


def test_002_step_responses_of_the_documents_designs():
    """[Checks] §5 "time-domain claims" (continuous simulations there) with the
    implemented law at h = 1 ms: P overshoot 46.4 % of the final value; PD: final 0.95
    (SSE 5.0 %), peak 1.0044, ±5 % after 0.35 s, 10–90 % rise 0.12 s; PI: overshoot 4.1 %,
    5 % band of the setpoint after 5.77 s ("nearly 6 s"); PID: no overshoot, ±5 % after
    0.32 s. The hold's half sample (0.5 ms) raises the lightly damped peaks slightly."""
    t, y, _ = simulate_002(9.5, 0.0, math.inf, t_end=20.0)
    assert 100 * (y.max() / y[-1] - 1) == pytest.approx(46.4, abs=0.5)
    t, y, _ = simulate_002(9.5, td_for(10.8), math.inf, t_end=3.0)
    assert y[-1] == pytest.approx(0.95, abs=1e-5)
    assert y.max() == pytest.approx(1.0044, abs=0.0015)
    assert settled_after(t, y, 0.95, 0.05) == pytest.approx(0.35, abs=0.01)
    rise = t[np.argmax(y >= 0.9 * 0.95)] - t[np.argmax(y >= 0.1 * 0.95)]
    assert rise == pytest.approx(0.12, abs=0.01)
    t, y, _ = simulate_002(2.0, 0.0, 4.2, t_end=30.0)
    assert 100 * (y.max() - 1) == pytest.approx(4.1, abs=0.1)
    assert settled_after(t, y, 1.0, 0.05) == pytest.approx(5.77, abs=0.02)
    t, y, _ = simulate_002(5.75, td_for(10.8), 4.2, t_end=12.0)
    assert y.max() <= 1.0 and settled_after(t, y, 1.0, 0.05) == pytest.approx(0.32, abs=0.01)


def test_peaks_differ_from_the_documents_continuous_ones_by_the_hold():
    """Where the sampled loop's peaks differ from the continuous simulation (P: 1.3912,
    [Checks] §5), the excess is the hold's: it grows in proportion to h."""
    num = 9.5 * np.array([4.0])
    t = np.linspace(0.0, 20.0, 200001)
    _, y_cont = signal.step((num, np.polyadd([1.0, 3.0, 2.0], num)), T=t)
    assert y_cont.max() == pytest.approx(1.3912, abs=1e-4)
    excess = [simulate_002(9.5, 0.0, math.inf, h=h, t_end=5.0)[1].max() - y_cont.max()
              for h in (0.001, 0.002, 0.004)]
    assert excess[0] > 0.0
    assert excess[1] / excess[0] == pytest.approx(2.0, rel=0.1)
    assert excess[2] / excess[1] == pytest.approx(2.0, rel=0.1)


def test_our_002_designs_meet_the_specification_in_time():
    """Our P/PD/PI/PID designs in the implemented loop: PD final error 5 % and overshoot
    (against the setpoint) < 5 %; PI and PID no steady-state error and < 5 % overshoot."""
    for kind in ('pd', 'pi', 'pid'):
        d = design_002(kind)
        t, y, _ = simulate_002(d.kp, d.td, d.ti, t_end=40.0)
        final = 0.95 if kind == 'pd' else 1.0
        assert y[-1] == pytest.approx(final, abs=2e-4), kind
        assert y.max() < 1.05, kind


def test_anti_windup_removes_the_overshoot_of_a_saturated_start():
    """Output limits [0, 0.55] on our PI loop (steady output 0.5 for the setpoint 1): the
    output never leaves the limits; plain integration winds up and overshoots, both
    anti-windup methods reach the setpoint without overshoot."""
    d = design_002('pi')
    over = {}
    for method in ('back_calculation', 'conditional_integration', 'none'):
        t, y, u = simulate_002(d.kp, 0.0, d.ti, h=0.01, t_end=80.0, u_min=0.0, u_max=0.55,
                               anti_windup=method)
        assert u.min() >= 0.0 and u.max() <= 0.55
        assert y[-1] == pytest.approx(1.0, abs=1e-3)
        over[method] = y.max() - 1.0
    assert over['none'] > 0.01
    assert over['back_calculation'] < 1e-4 and over['conditional_integration'] < 1e-4


# ------------------------------------------------------------- other plants and models
def test_fopdt_and_ipdt_designs_meet_their_targets_with_exact_dead_time():
    """The design's closed-form margins checked with frequency.py (exact dead time):
    PI on the [DeadTimeNotes] FOPDT and the [Viteckova] IPDT has exactly the target margin; PD on an FOPDT
    at least the target; every loop is stable (Nyquist)."""
    cases = [('pi', dict(model='fopdt', gain=0.05, time_constant=10.0, dead_time=3.0),
              fr.fopdt(0.05, 10.0, 3.0)),
             ('pi', dict(model='ipdt', gain=0.05, dead_time=5.0), fr.ipdt(0.05, 5.0)),
             ('pd', dict(model='fopdt', gain=1.0, time_constant=10.0, dead_time=1.0,
                         steady_state_error=0.1), fr.fopdt(1.0, 10.0, 1.0)),
             ('pid', dict(model='fopdt', gain=1.0, time_constant=10.0, dead_time=1.0,
                          steady_state_error=0.1, phase_margin=50.0), fr.fopdt(1.0, 10.0, 1.0))]
    for kind, model, plant in cases:
        d = design(LeadLagTuning(rule='frequency_002', kind=kind, **model), ALPHA)
        loop = continuous_response(d.kp, d.td, ALPHA, d.ti) * plant
        m = fr.margins(loop)
        assert fr.closed_loop_stable(loop), (kind, model)
        assert m.phase_margin == pytest.approx(d.phase_margin, abs=1e-6), (kind, model)
        target = model.get('phase_margin', 60.0)
        if kind == 'pi':
            assert m.phase_margin == pytest.approx(target, abs=1e-6)
        else:
            assert m.phase_margin >= target - 1e-9
        if kind == 'pd':                               # [Ikonen] §1.1: 1/(1 + kp·K) = 10 %
            assert d.kp == pytest.approx(9.0, rel=1e-12)


@pytest.mark.parametrize('kind,model,name', [
    ('pd', dict(model='ipdt', gain=0.05, dead_time=5.0), 'tuning.kind'),
    ('pd', dict(model='fopdt', gain=0.05, time_constant=10.0, dead_time=3.0),
     'tuning.phase_margin'),
    ('pi', dict(model='fopdt', gain=1.0, time_constant=10.0), 'tuning.model'),
    ('pi', dict(model='fopdt', gain=0.0, time_constant=10.0), 'tuning.gain'),
    ('pi', dict(model='sopdt', gain=1.0, time_constant=10.0), 'tuning.time_constant2'),
    ('pi', dict(model='ipdt', gain=1.0, time_constant=10.0, dead_time=1.0),
     'tuning.time_constant'),
    ('pi', dict(model='ipdt', gain=1.0, dead_time=1.0, phase_margin=89.0), 'tuning.phase_margin'),
])
def test_out_of_reach_or_inapplicable_designs_are_refused_naming_the_parameter(kind, model,
                                                                              name):
    with pytest.raises(ValueError) as info:
        design(LeadLagTuning(rule='frequency_002', kind=kind, **model), ALPHA)
    assert str(info.value).startswith(name + ':'), str(info.value)
    assert '\n' not in str(info.value)
