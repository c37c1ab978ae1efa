"""[Ikonen]'s design procedure (core/tuning/design_002.py) against numbers derived here by hand or
with independent tools, and the shipped [Ikonen] scenarios (config/scenarios/tf_002_*.yaml) run
in-process with the document's time-domain claims asserted on the measured trace
(docs/scenarios.md, [Ikonen]; [Checks] §5)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal
from support import SCENARIOS

from tank_control.core import scenario
from tank_control.core.analysis import frequency as fr
from tank_control.core.params import ConfigError
from tank_control.core.tuning import design_002 as d
from tank_control.core.tuning.model import ProcessModel

G_002 = fr.rational([4.0], [1.0, 3.0, 2.0])          # [Ikonen]'s process 4/((s + 1)(s + 2))
MODEL_002 = ProcessModel('sopdt', 2.0, 0.0, 1.0, 0.5)  # the same, as the lead_lag kind's model
T_STEP = 1.0                                           # [s] the scenarios' setpoint step


def loop_at(kp, td, alpha, ti, w):
    """C(jω)·G(jω) written out here with numpy (not frequency.py)."""
    s = 1j * w
    c = kp * ((td * s + 1) / (alpha * td * s + 1) if td else 1.0)
    c *= (1 + 1 / (ti * s)) if math.isfinite(ti) else 1.0
    return c * 4.0 / ((s + 1) * (s + 2))


# ------------------------------------------------------------ PM ↔ damping ↔ overshoot
def test_phase_margin_damping_overshoot_chain():
    """[Ikonen] §1.2: ζ ≈ PM/100, Mp = exp(−πζ/√(1 − ζ²)); the document's 5 % → ζ 0.6 → 60°.
    By the same formulas 5 % needs ζ = 0.690 (69.0°) and ζ = 0.6 gives 9.48 %."""
    assert d.damping_from_phase_margin(60.0) == 0.6
    assert d.phase_margin_from_damping(0.6) == pytest.approx(60.0)
    assert d.overshoot_from_damping(0.6) == pytest.approx(math.exp(-0.6 * math.pi / 0.8))
    assert round(100 * d.overshoot_from_damping(0.6), 2) == 9.48
    assert round(d.damping_from_overshoot(0.05), 3) == 0.690
    assert round(d.phase_margin_for_overshoot(0.05), 1) == 69.0
    for zeta in (0.1, 0.3, 0.6, 0.9):
        assert d.damping_from_overshoot(d.overshoot_from_damping(zeta)) == pytest.approx(zeta)
    assert d.overshoot_from_damping(1.0) == 0.0
    with pytest.raises(ValueError):
        d.damping_from_overshoot(0.0)


@pytest.mark.parametrize('zeta', [0.3, 0.6, 0.69])
def test_the_rule_against_the_second_order_loop(zeta):
    """The loop ω_n²/(s(s + 2ζω_n)): its phase margin by frequency.py is
    :func:`exact_phase_margin` (59.2° for ζ 0.6: the rule's 60° is close), and the overshoot
    of its closed loop, simulated by scipy, is :func:`overshoot_from_damping`."""
    wn = 3.0
    m = fr.margins(fr.rational([wn ** 2], [1.0, 2 * zeta * wn, 0.0]))
    assert m.phase_margin == pytest.approx(d.exact_phase_margin(zeta), abs=1e-6)
    assert abs(d.exact_phase_margin(zeta) - 100 * zeta) < 5.0
    t = np.linspace(0.0, 20.0, 200_001)
    _, y = signal.step(([wn ** 2], [1.0, 2 * zeta * wn, wn ** 2]), T=t)
    assert y.max() - 1.0 == pytest.approx(d.overshoot_from_damping(zeta), abs=1e-6)


# ------------------------------------------------------------------------ the pieces
def test_p_gain_and_its_steady_state_error():
    """[Ikonen] §1.1: 1/(1 + 2·kp) = 0.05 → kp = 9.5."""
    assert d.p_gain(2.0, 0.05) == pytest.approx(9.5, rel=1e-15)
    assert d.steady_state_error(9.5, 2.0) == pytest.approx(0.05)
    assert d.static_gain(G_002) == 2.0 and d.static_gain(MODEL_002) == 2.0
    assert d.static_gain(fr.ipdt(0.05, 5.0)) == math.inf
    with pytest.raises(ConfigError, match='^tuning.kind:'):
        d.p_gain(math.inf, 0.05)


def test_lead_largest_phase_where_and_how_much():
    """[Ikonen] §1.2: (Td s + 1)/(α Td s + 1) has its largest phase asin((1 − α)/(1 + α)) (54.9°
    for α = 0.1) at ω_max = 1/(Td√α): read off a dense grid of frequency.py's response."""
    assert d.lead_max_phase(0.1) == pytest.approx(math.degrees(math.asin(9 / 11)))
    assert round(d.lead_max_phase(0.1), 1) == 54.9
    assert round(d.lead_time(6.0, 0.1), 3) == 0.527 and round(d.lead_time(10.8, 0.1), 4) == 0.2928
    td = d.lead_time(6.0, 0.1)
    assert d.lead_w_max(td, 0.1) == pytest.approx(6.0)
    w = np.logspace(-1, 3, 40_001)
    _, _, phase = fr.bode(d.controller_response(1.0, td, 0.1), w)
    assert w[np.argmax(phase)] == pytest.approx(6.0, rel=1e-3)
    assert phase.max() == pytest.approx(d.lead_max_phase(0.1), abs=1e-6)


def test_integral_corner_a_decade_below():
    """[Ikonen] §1.3: Ti = 10/2.4 = 4.17 → 4.2 s."""
    assert d.integral_time(2.4) == pytest.approx(4.1667, abs=1e-4)
    assert d.integral_time(2.0, ratio=5.0) == 2.5


# ------------------------------------------------------------------- the designs
@pytest.mark.parametrize('kind', d.KINDS)
def test_design_on_the_transfer_function_equals_the_design_on_the_model(kind):
    """The same process given as num/den (the transfer_function plant) and as the sopdt
    model gives the same design."""
    a, b = d.design(G_002, kind), d.design(MODEL_002, kind)
    assert (a.kp, a.td, a.ti, a.phase_margin, a.wc) == pytest.approx(
        (b.kp, b.td, b.ti, b.phase_margin, b.wc), rel=1e-9)


@pytest.mark.parametrize('kind', d.KINDS)
def test_designed_loop_has_the_reported_margin_at_the_reported_crossover(kind):
    """At the design's crossover |C·G| = 1 and 180° + ∠C·G is its phase margin, both from
    numpy directly; the closed loop is stable (its poles by numpy's roots)."""
    x = d.design(G_002, kind)
    value = loop_at(x.kp, x.td, 0.1, x.ti, x.wc)
    assert abs(value) == pytest.approx(1.0, abs=1e-9)
    assert 180.0 + math.degrees(np.angle(value)) == pytest.approx(x.phase_margin, abs=1e-7)
    num, den = np.array([x.kp * 4.0]), np.array([1.0, 3.0, 2.0])
    if x.td:
        num, den = np.convolve(num, [x.td, 1]), np.convolve(den, [0.1 * x.td, 1])
    if math.isfinite(x.ti):
        num, den = np.convolve(num, [x.ti, 1]), np.convolve(den, [x.ti, 0])
    assert np.all(np.roots(np.polyadd(den, num)).real < 0)


def test_p_design_reproduces_fig_2():
    """Fig. 2: "Pm = 28.1 deg (at 5.96 rad/s)"; by hand 38² = (ω² + 1)(ω² + 4)."""
    x = d.design(G_002, 'p')
    wc = math.sqrt((-5 + math.sqrt(25 + 4 * (38 ** 2 - 4))) / 2)
    assert x.kp == pytest.approx(9.5) and x.wc == pytest.approx(wc, rel=1e-9)
    assert round(x.phase_margin, 1) == 28.1 and round(x.wc, 2) == 5.96


def test_lead_iteration_steps_and_target():
    """[Ikonen] §1.2: ω_max first at the P crossover, then the mean of it and the new crossover;
    each step's margin is frequency.py's; the last meets the 60° target (70.5° at 10.9 rad/s,
    Td 0.29 s: Fig. 6)."""
    steps = d.lead_iteration(G_002, 9.5, 60.0, 0.1)
    assert len(steps) == 2
    assert steps[0].w_max == pytest.approx(d.design(G_002, 'p').wc)
    assert steps[1].w_max == pytest.approx(0.5 * (steps[0].w_max + steps[0].wc))
    for step in steps:
        m = fr.margins(d.controller_response(9.5, step.td, 0.1) * G_002)
        assert (step.phase_margin, step.wc) == pytest.approx((m.phase_margin, m.wc), rel=1e-9)
        assert step.td == pytest.approx(d.lead_time(step.w_max, 0.1))
    assert steps[0].phase_margin < 60.0 <= steps[1].phase_margin
    x = d.design(G_002, 'pd')
    assert x.lead_steps == steps
    assert (round(x.phase_margin, 1), round(x.wc, 1), round(x.td, 2)) == (70.5, 10.9, 0.29)
    # the iteration's fixed point puts ω_max at the crossover (70.62° at 10.848 rad/s); a
    # higher target stops there and the design refuses it, naming the parameter
    more = d.lead_iteration(G_002, 9.5, 72.0, 0.1)
    assert len(more) > 2 and more[-1].w_max == pytest.approx(more[-1].wc, rel=1e-6)
    assert round(more[-1].phase_margin, 2) == 70.62
    with pytest.raises(ConfigError, match='^tuning.phase_margin: 72 deg is out of reach'):
        d.design(G_002, 'pd', phase_margin=72.0)


def test_pi_design_meets_its_target_and_gives_the_documents_pi_at_its_margin():
    """The PI loop has exactly the target (frequency.py) with Ti = 10/(its P loop's
    crossover); asked for the 57.07° that [Ikonen]'s kp 2, Ti 4.2 s has (Fig. 10), the design
    gives back kp 2.00, Ti 4.21 s: the document's PI is this design at a lower target."""
    x = d.design(G_002, 'pi')
    assert fr.margins(fr.pi(x.kp, x.ti) * G_002).phase_margin == pytest.approx(60.0, abs=1e-7)
    assert x.ti == pytest.approx(10.0 / fr.margins(x.kp * G_002).wc, rel=1e-9)
    doc = fr.margins(fr.pi(2.0, 4.2) * G_002)
    assert round(doc.phase_margin, 1) == 57.1
    again = d.design(G_002, 'pi', phase_margin=doc.phase_margin)
    assert round(again.kp, 2) == 2.00 and round(again.ti, 2) == 4.21


def test_series_pid_is_the_product_with_the_mean_gain():
    pd, pi, x = (d.design(G_002, k) for k in ('pd', 'pi', 'pid'))
    assert (x.kp, x.td, x.ti) == pytest.approx(((pd.kp + pi.kp) / 2, pd.td, pi.ti))
    c = d.controller_response(x.kp, x.td, 0.1, x.ti)
    product = d.controller_response(1.0, pd.td, 0.1) * fr.pi(x.kp, pi.ti)
    w = np.logspace(-2, 3, 50)
    assert np.allclose(c(w), product(w), rtol=1e-12)
    assert round(x.phase_margin) == 75 and round(x.wc) == 7     # Fig. 17: 75° at 7 rad/s


def test_design_with_dead_time_on_a_third_order_process():
    """Beyond [Ikonen]: 1/(s + 1)³ with 0.2 s dead time — the PD and PI meet 45° (frequency.py with
    the exact delay), stable by the Nyquist count. The series PID's mean gain is [Ikonen]'s
    heuristic, not a design for the margin: here it has 43.0°."""
    g = fr.rational([1.0], [1.0, 3.0, 3.0, 1.0], 0.2)
    for kind in ('pd', 'pi', 'pid'):
        x = d.design(g, kind, error=0.3, phase_margin=45.0)
        loop = d.controller_response(x.kp, x.td, 0.1, x.ti) * g
        assert fr.closed_loop_stable(loop)
        assert fr.margins(loop).phase_margin == pytest.approx(x.phase_margin, abs=1e-9)
        if kind != 'pid':
            assert x.phase_margin >= 45.0 - 1e-9
    assert d.design(g, 'pi', phase_margin=45.0).phase_margin == pytest.approx(45.0, abs=1e-7)
    assert round(d.design(g, 'pid', error=0.3, phase_margin=45.0).phase_margin, 1) == 43.0


def test_refusals_name_the_parameter():
    with pytest.raises(ConfigError, match='^tuning.phase_margin:'):
        d.design(fr.fopdt(0.05, 10.0, 3.0), 'pd', phase_margin=60.0)
    with pytest.raises(ConfigError, match='^tuning.kind:'):
        d.design(G_002, 'pdd')
    with pytest.raises(ValueError, match='continuous'):
        d.design(MODEL_002.response(0.1), 'p')


# ------------------------------------------------------------------ shipped scenarios
def run(name: str, **controller: object):
    """The scenario run in-process (core/scenario.py) with controller overrides; returns
    (t after the step, y after the step, u, the controller's parameter values)."""
    sections = scenario.sections_of(SCENARIOS / f'{name}.yaml')
    sections['controller'].update(controller)
    built = scenario.build(sections)
    trace = scenario.run(built, scenario.duration_of(sections, None))
    after = trace.t >= T_STEP
    return (trace.t[after] - T_STEP, trace['y.y'][after], trace['u.u'][after],
            built.controller_values())


def band_entry(t, y, ref, band):
    """Time after the step from which |y − ref| ≤ band·|ref|."""
    outside = np.flatnonzero(np.abs(y - ref) > band * abs(ref))
    return float(t[outside[-1] + 1]) if outside.size else 0.0


def rise_time(t, y, final):
    return float(t[np.argmax(y >= 0.9 * final)] - t[np.argmax(y >= 0.1 * final)])


@pytest.mark.parametrize('name, kind', [('tf_002_p', 'p'), ('tf_002_pd', 'pd'),
                                        ('tf_002_pi_designed', 'pi'), ('tf_002_pid', 'pid')])
def test_scenario_runs_the_design_it_names(name, kind):
    """The file gives only the rule and the model; the controller runs the design's gains."""
    *_, values = run(name)
    x = d.design(MODEL_002, kind)
    assert values['tuning.rule'] == 'frequency_002' and values['controller'] == 'lead_lag'
    assert values['lead_lag.kp'] == pytest.approx(x.kp, rel=1e-12)
    assert values['lead_lag.td'] == pytest.approx(x.td, rel=1e-12)
    assert values['lead_lag.ti'] == pytest.approx(x.ti if math.isfinite(x.ti) else 0.0,
                                                  rel=1e-12)


def test_002_p_overshoots_more_than_40_percent_and_oscillates():
    """Fig. 1: "overshoot more than 40 %", strong oscillation; SSE 5 %. Measured (h 0.01 s):
    peak 1.4145 = 48.9 % above the final 0.95 (continuous 46.4 %), 41.4 % above the
    setpoint (continuous 39.1 %: only the final-value overshoot exceeds 40 % in the
    continuous loop); three peaks over the final value by more than 1 % of the step."""
    t, y, _, _ = run('tf_002_p')
    final = y[-1]
    assert final == pytest.approx(0.95, abs=1e-4)
    assert 100 * (y.max() / final - 1) > 40.0
    e = y - final
    peaks = np.flatnonzero((e[1:-1] > e[:-2]) & (e[1:-1] >= e[2:]) & (e[1:-1] > 0.01)) + 1
    assert len(peaks) >= 3


def test_002_pd_meets_5_percent_overshoot_and_error_a_decade_faster():
    """Fig. 7: overshoot and steady-state error criteria (5 %, 5 %) met, about a decade faster
    than the open loop. Measured: final 0.95 (error 5.0 %), peak 1.0166, i.e. 1.7 % above the
    setpoint (continuous 0.4 %) but 7.0 % above the final value (continuous 5.7 %): the
    criterion holds against the setpoint. Rise 0.11 s against the open loop's 2.59 s."""
    t, y, _, _ = run('tf_002_pd')
    final = y[-1]
    assert 1.0 - final <= 0.05 + 1e-6 and final == pytest.approx(0.95, abs=1e-4)
    assert y.max() <= 1.05
    tt = np.linspace(0.0, 20.0, 200_001)
    _, y_open = signal.step(([4.0], [1.0, 3.0, 2.0]), T=tt)
    assert rise_time(t, y, final) < rise_time(tt, y_open, 2.0) / 10
    assert band_entry(t, y, final, 0.05) < 0.5


def test_002_pi_of_the_document_within_5_percent_after_about_6_s():
    """Fig. 11 (kp 2, Ti 4.2 s, tf_002_pi): criteria met, within the 5 % band after "nearly
    6 s". Measured 5.76 s, overshoot 4.6 %, no final error."""
    sections = scenario.sections_of(SCENARIOS / 'tf_002_pi.yaml')
    trace = scenario.run_in_process(sections)
    after = trace.t >= T_STEP
    t, y = trace.t[after] - T_STEP, trace['y.y'][after]
    assert 5.0 <= band_entry(t, y, 1.0, 0.05) <= 6.0
    assert y.max() <= 1.05 and abs(y[-1] - 1.0) < 1e-3


def test_002_pi_designed_for_60_deg_is_slower_than_the_documents():
    """tf_002_pi_designed (exactly 60°: kp 1.839, Ti 4.469 s): zero final error, overshoot
    1.5 %, in the 5 % band after 6.77 s — the document's 57.1° PI gets there at 5.77 s.
    The cause, measured: the same file asked for 57.07° designs kp 2.00, Ti 4.21 s and
    enters the band after 5.77 s."""
    t, y, _, _ = run('tf_002_pi_designed')
    assert y.max() <= 1.05 and abs(y[-1] - 1.0) < 2e-3
    assert 6.5 <= band_entry(t, y, 1.0, 0.05) <= 7.0
    t, y, _, values = run('tf_002_pi_designed', **{'tuning.phase_margin': 57.07})
    assert round(values['lead_lag.kp'], 2) == 2.00 and round(values['lead_lag.ti'], 2) == 4.21
    assert 5.0 <= band_entry(t, y, 1.0, 0.05) <= 6.0


def test_002_pid_fast_start_and_no_final_error():
    """Fig. 13: the PD's fast start with the PI's zero error. Measured: no overshoot, within
    5 % after 0.32 s (the PD's 0.36 s), 2 % after 5.4 s (the integral's slow tail)."""
    t, y, _, _ = run('tf_002_pid')
    assert y.max() <= 1.0 + 1e-3
    assert band_entry(t, y, 1.0, 0.05) < 0.4
    assert abs(y[-1] - 1.0) < 1e-3


def test_the_command_prints_the_worked_example(capsys):
    """``python -m tank_control.core.tuning.design_002`` (docs/tuning.md): [Ikonen]'s process by
    default, the steps and the four designs; a refused design is a line, not a crash."""
    assert d.main([]) == 0
    out = capsys.readouterr().out
    assert 'p    kp 9.5  td 0 s  ti inf s  PM 28.07 deg at 5.961 rad/s' in out
    assert 'lead step: w_max 5.961 rad/s  td 0.5305 s  PM 54.64 deg at 15.52 rad/s' in out
    assert 'pi   kp 1.839  td 0 s  ti 4.469 s  PM 60.00 deg at 2.246 rad/s' in out
    assert d.main(['--phase-margin', '72']) == 0
    assert 'pd   refused: tuning.phase_margin: 72 deg is out of reach' in capsys.readouterr().out
