"""Robustness of a scenario's SISO loop on its linear models: a table and ``analysis.png``.

A SISO loop is analysed when its controller kind and its plant kind describe themselves
(``ControllerKind.linear``, ``PlantKind.linear``: ``core/analysis/linear.py``,
``core/analysis/loops.py``). The loop analysed is the implemented one: the exact ZOH model at
the controller's sample time and the controller's discrete transfer function (exact dead time,
SPEC §3, [Ikonen]'s gang of four). The plant section gives the true model; the models the
controller carries (``tuning.*``, the auto-tuner's identified one, a predictor's internal
model) are analysed beside it. Frequencies in rad/s, phase in degrees, delay margin in s.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.linear import frequency_scale
from tank_control.core.analysis.loops import LoopCase, describe_loop, loop_cases


def _num(value: float, fmt: str = '.3g') -> str:
    if isinstance(value, float) and math.isinf(value):
        return 'inf'
    if isinstance(value, float) and math.isnan(value):
        return '-'
    return format(value, fmt)


def robustness_table(cases: list[LoopCase]) -> str:
    """A Markdown table: one row per case with stability (Nyquist, exact delay), gain margin,
    phase margin [deg], Ms, Mt, delay margin [s], crossover [rad/s]."""
    if not cases:
        return ''
    c = cases[0].controller
    head = (f'loop {cases[0].output} <- {cases[0].input}: {c.describe}; implemented discrete '
            f'loop, h = {c.sample_time:g} s\n\n')
    lines = ['| model | stable | GM | PM [deg] | Ms | Mt | delay margin [s] | crossover [rad/s] |',
             '|---|---|---|---|---|---|---|---|']
    for case in cases:
        r = case.report()
        lines.append(f'| {case.label} | {"yes" if r.stable else "NO"} | {_num(r.gain_margin)} | '
                     f'{_num(r.phase_margin, ".1f")} | {_num(r.ms)} | {_num(r.mt)} | '
                     f'{_num(r.delay_margin)} | {_num(r.wc)} |')
    return head + '\n'.join(lines) + '\n'


def plot_analysis(cases: list[LoopCase], path: str | Path, title: str = '') -> Path:
    """``analysis.png``: Bode of the loop gain L with the margins marked, Nyquist of L with
    the Ms circle (centre −1, radius 1/Ms) and the unit circle's −1 point, and the gang of
    four |S|, |T|, |PS|, |CS| — one colour per case, exact delay, up to the Nyquist frequency."""
    from tank_control.harness.plotting import plt, save_figure   # the Agg backend
    path = Path(path)
    fig, axes = plt.subplots(2, 2, figsize=(12, 9))
    (ax_mag, ax_nyq), (ax_ph, ax_g4) = axes
    for i, case in enumerate(cases):
        color = f'C{i}'
        h = case.controller.sample_time
        plant = case.model.response(h)
        ctrl = case.controller.feedback
        loop = ctrl * plant
        rep = case.report()
        wu = frequency_scale(case.model)
        hi = math.pi / h * (1 - 1e-9)
        w = np.logspace(math.log10(min(wu / 200.0, hi / 1e4)), math.log10(hi), 1500)
        w, mag, phase = fr.bode(loop, w)
        ax_mag.loglog(w, mag, color=color, label=case.label)
        ax_ph.semilogx(w, phase, color=color)
        if math.isfinite(rep.wc):
            ax_mag.axvline(rep.wc, color=color, ls=':', lw=0.8)
            ax_ph.plot([rep.wc], [rep.phase_margin - 180.0], 'o', color=color)
            ax_ph.annotate(f'PM {rep.phase_margin:.1f}°', (rep.wc, rep.phase_margin - 180.0),
                           textcoords='offset points', xytext=(5, 5 + 12 * i), color=color,
                           fontsize='small')
        if math.isfinite(rep.w180):
            ax_mag.plot([rep.w180], [1.0 / rep.gain_margin], 's', color=color)
            ax_mag.annotate(f'GM {rep.gain_margin:.2f}', (rep.w180, 1.0 / rep.gain_margin),
                            textcoords='offset points', xytext=(5, -12 - 12 * i), color=color,
                            fontsize='small')
        values = loop(w)
        ax_nyq.plot(values.real, values.imag, color=color, label=f'{case.label}: Ms {rep.ms:.2f}')
        theta = np.linspace(0, 2 * math.pi, 200)
        ax_nyq.plot(-1 + np.cos(theta) / rep.ms, np.sin(theta) / rep.ms, '--', color=color,
                    lw=0.8)
        g4 = fr.gang_of_four(ctrl, plant, w)
        for name, style in (('S', '-'), ('T', '--'), ('PS', '-.'), ('CS', ':')):
            ax_g4.loglog(w, np.abs(g4[name]), style, color=color,
                         label=f'|{name}|' if i == 0 else None)
    ax_mag.axhline(1.0, color='k', lw=0.6)
    ax_mag.set_ylabel('|L(jω)|')
    ax_mag.set_title('loop gain L = C·G (exact delay, ZOH)')
    ax_mag.legend(fontsize='small')
    ax_ph.axhline(-180.0, color='k', lw=0.6)
    ax_ph.set_ylim(-540.0, 0.0)                       # the dead time's phase falls without end
    ax_ph.set_ylabel('phase of L [deg]')
    ax_ph.set_xlabel('ω [rad/s]')
    ax_nyq.plot([-1], [0], 'k+', ms=10)
    ax_nyq.set_xlim(-3, 1.5)
    ax_nyq.set_ylim(-2.5, 2.0)
    ax_nyq.set_aspect('equal')
    ax_nyq.set_title('Nyquist of L with the Ms circle')
    ax_nyq.set_xlabel('Re L')
    ax_nyq.set_ylabel('Im L')
    ax_nyq.legend(fontsize='small')
    ax_g4.set_title('gang of four ([Ikonen])')
    ax_g4.set_xlabel('ω [rad/s]')
    ax_g4.legend(fontsize='small')
    for ax in axes.flat:
        ax.grid(True, alpha=0.3, which='both')
    return save_figure(fig, path, title, dpi=90)


def analyze(path: str | Path, overrides: tuple[str, ...] = ()) -> str:
    """The robustness table of a scenario file's controller on its plant model (and on the
    controller's own models), without running it; a line saying why when there is no SISO
    loop with linear descriptions to analyse."""
    from tank_control.core import scenario as core_scenario
    from tank_control.harness.scenario_file import load_scenario
    scenario = load_scenario(path, overrides)
    cases = loop_cases(scenario.sections)
    if not cases:
        try:
            _, reason = describe_loop(core_scenario.node_values(scenario.sections, 'plant'),
                                      core_scenario.node_values(scenario.sections, 'controller'))
        except (ValueError, ArithmeticError) as exc:
            reason = str(exc)
        return f'{scenario.path}: no SISO loop to analyse: {reason}\n'
    return robustness_table(cases)
