"""Robustness of a scenario's SISO loop on its linear models: a table and ``analysis.png``.

A SISO loop is analysed when its controller kind and its plant kind describe themselves
(``ControllerKind.linear``, ``PlantKind.linear``: ``core/analysis/linear.py``,
``core/scenario_loops.py``). The loop analysed is the implemented one: the exact ZOH model at
the controller's sample time and the controller's discrete transfer function (exact dead time,
[Checks] §2, [Ikonen]'s gang of four). The plant section gives the true model; the models the
controller carries (``tuning.*``, the auto-tuner's identified one, a predictor's internal
model) are analysed beside it. Frequencies in rad/s, phase in degrees, delay margin in s.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.linear import frequency_scale
from tank_control.core.scenario_loops import LoopCase, describe_loop, loop_cases

if TYPE_CHECKING:
    from tank_control.core.analysis.two_loop import TwoLoopAnalysis


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


#: analysis.png's layout (2 × 3 panels at 17 × 9 in): the labels fit, no tight_layout pass
ANALYSIS_MARGINS = {'left': 0.05, 'right': 0.985, 'top': 0.92, 'bottom': 0.07, 'wspace': 0.22,
                    'hspace': 0.28}


def plot_analysis(cases: list[LoopCase], path: str | Path, title: str = '') -> Path:
    """``analysis.png``: Bode of the loop gain L with the margins marked, Nyquist of L with
    the Ms circle (centre −1, radius 1/Ms) and the unit circle's −1 point, and the gang of
    four |S|, |T|, |PS|, |CS| — one colour per case, exact delay, up to the Nyquist frequency."""
    from tank_control.harness.plotting import plt, save_figure   # the Agg backend
    path = Path(path)
    fig, axes = plt.subplots(2, 3, figsize=(17, 9))
    (ax_mag, ax_nyq, ax_step), (ax_ph, ax_g4, ax_free) = axes
    ax_free.axis('off')
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
        if rep.stable:
            t_step, y_step = predicted_step(case)
            ax_step.plot(t_step, y_step, color=color, label=case.label)
        g4 = fr.gang_of_four(ctrl, plant, w)
        for name, style in (('S', '-'), ('T', '--'), ('PS', '-.'), ('CS', ':')):
            ax_g4.loglog(w, np.abs(g4[name]), style, color=color,
                         label=f'|{name}|' if i == 0 else None)
    ax_mag.axhline(1.0, color='k', lw=0.6)
    ax_mag.set_ylabel('|L(jω)|')
    ax_mag.set_title('loop gain L = C·G (exact delay, ZOH)', y=1.0)
    ax_mag.legend(fontsize='small')
    ax_ph.axhline(-180.0, color='k', lw=0.6)
    ax_ph.set_ylim(-540.0, 0.0)                       # the dead time's phase falls without end
    ax_ph.set_ylabel('phase of L [deg]')
    ax_ph.set_xlabel('ω [rad/s]')
    ax_nyq.plot([-1], [0], 'k+', ms=10)
    ax_nyq.set_xlim(-3, 1.5)
    ax_nyq.set_ylim(-2.5, 2.0)
    ax_nyq.set_aspect('equal')
    ax_nyq.set_title('Nyquist of L with the Ms circle', y=1.0)
    ax_nyq.set_xlabel('Re L')
    ax_nyq.set_ylabel('Im L')
    ax_nyq.legend(fontsize='small')
    ax_step.axhline(1.0, color='k', lw=0.6)
    ax_step.set_title('predicted setpoint step y/r (linear, stable loops)', y=1.0)
    ax_step.set_xlabel('t [s]')
    ax_step.set_ylabel('y for a unit step of r')
    ax_g4.set_title('gang of four ([Ikonen])', y=1.0)
    ax_g4.set_xlabel('ω [rad/s]')
    ax_g4.legend(fontsize='small')
    for ax in (ax_mag, ax_nyq, ax_step, ax_ph, ax_g4):
        _grid(ax)
    return save_figure(fig, path, title, dpi=90, margins=ANALYSIS_MARGINS)


def _grid(ax: Any) -> None:
    """A grid at the major ticks and, on a log axis, minor lines at 2 and 5 of each decade
    without labels (matplotlib's default, 2 to 9 with labels on a short axis, made the
    figure twice as slow to draw: its ticks are most of the drawing)."""
    from matplotlib.ticker import LogLocator, NullFormatter
    for axis in (ax.xaxis, ax.yaxis):
        if axis.get_scale() == 'log':
            axis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
            axis.set_minor_formatter(NullFormatter())
    ax.grid(True, alpha=0.3, which='both')


def predicted_step(case: LoopCase, samples: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(t [s], y)``: the closed loop's response to a unit setpoint step at the controller's
    samples, ``Y/R = G·C_r/(1 + G·C)`` of the implemented discrete loop (exact delay), from its
    values on the unit circle by an inverse FFT (for a stable loop). The FFT gives the response
    of a periodic record, so the record is doubled until the first half agrees with the
    doubled record to 1e-7 (a slow tail, e.g. an integral's, would otherwise wrap around; at
    most 2^18 samples): 40/crossover + 4 dead times, at least 512 samples, to begin with;
    ``samples``: exactly that many, no doubling."""
    h = case.controller.sample_time
    if samples is not None:
        return _step_by_fft(case, samples)
    rep = case.report()
    span = 40.0 / rep.wc if math.isfinite(rep.wc) and rep.wc > 0 else 1000.0 * h
    n = int(min(2 ** 16, max(512, (span + 4.0 * case.model.dead_time) / h)))
    t, y = _step_by_fft(case, n)
    while 2 * n <= 2 ** 18:
        t2, y2 = _step_by_fft(case, 2 * n)
        if np.max(np.abs(y2[:len(y)] - y)) <= 1e-7:
            return t, y
        n, t, y = 2 * n, t2, y2
    return t, y


def _step_by_fft(case: LoopCase, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`predicted_step` on a record of ``samples`` (even) samples."""
    h = case.controller.sample_time
    n = 2 * (samples // 2)
    theta = 2.0 * math.pi * np.arange(1, n // 2 + 1) / n
    w = np.minimum(theta / h, math.pi / h * (1 - 1e-12))
    plant = case.model.response(h)(w)
    fb = case.controller.feedback(w)
    sp = fb if case.controller.setpoint is None else case.controller.setpoint(w)
    half = plant * sp / (1.0 + plant * fb)
    w0 = theta[0] * 1e-3 / h                 # the static value, from just above ω = 0
    g0, c0 = case.model.response(h)(w0), case.controller.feedback(w0)
    s0 = c0 if case.controller.setpoint is None else case.controller.setpoint(w0)
    static = complex(g0 * s0 / (1.0 + g0 * c0)).real
    spectrum = np.concatenate([[static], half[:-1], [half[-1].real], np.conj(half[-2::-1])])
    impulse = np.fft.ifft(spectrum).real[:n]
    return np.arange(n) * h, np.cumsum(impulse)


def _report_dict(case: LoopCase) -> dict[str, object]:
    r = case.report()
    return {'model': case.label, 'output': case.output, 'input': case.input,
            'controller': case.controller.describe, 'sample_time': case.controller.sample_time,
            'stable': bool(r.stable), 'gain_margin': r.gain_margin,
            'phase_margin': r.phase_margin, 'ms': r.ms, 'mt': r.mt,
            'delay_margin': r.delay_margin, 'crossover': r.wc, 'phase_crossover': r.w180}


def _two_loop(sections: dict, controller_values: Mapping[str, Any] | None = None
              ) -> tuple[TwoLoopAnalysis, str] | None:
    """The two-loop PI on the linearised mixing tank ([Precup2013] eq. 3.7.4, continuous, the
    document's analysis): ``(TwoLoopAnalysis, label)``, or None for another loop.
    ``controller_values``: the controller's parameters after a run, default the file's."""
    from tank_control.core import scenario as core_scenario
    from tank_control.core.analysis.two_loop import LinearisedTank, TwoLoopAnalysis
    from tank_control.core.control.multiloop import TwoLoopPiConfig
    if controller_values is None:
        controller_values = core_scenario.node_values(sections, 'controller')
    controller = core_scenario.controller_setup(controller_values, given=())
    config = controller.settings.config
    if not isinstance(config, TwoLoopPiConfig):
        return None
    plant = core_scenario.plant_setup(core_scenario.node_values(sections, 'plant'))
    model = plant.model
    if not hasattr(model, 'h_op'):
        return None
    tank = LinearisedTank.from_config(model)
    return TwoLoopAnalysis(tank, config), (
        f'two-loop PI (decoupling {config.decoupling}) on the mixing tank linearised at '
        f'h {model.h_op:g} cm; continuous, exact delays')


def _two_loop_table(analysis: TwoLoopAnalysis, label: str) -> tuple[str, list[dict[str, object]]]:
    """Each loop's margins with the other loop open and closed ([Precup2013] eq. 3.7.4)."""
    from tank_control.core.analysis.two_loop import LOOPS
    rows, out = [], []
    for i, name in enumerate(LOOPS):
        for closed in (False, True):
            m = analysis.margins(i, other_closed=closed)
            loop = analysis.loop(i, other_closed=closed)
            stable = fr.closed_loop_stable(loop)
            other = f'{LOOPS[1 - i]} {"closed" if closed else "open"}'
            out.append({'loop': name, 'other_loop': other, 'stable': bool(stable),
                        'gain_margin': m.gain_margin, 'phase_margin': m.phase_margin,
                        'ms': m.ms, 'mt': m.mt, 'delay_margin': m.delay_margin,
                        'crossover': m.wc, 'phase_crossover': m.w180})
            rows.append(f'| {name} | {other} | {"yes" if stable else "NO"} | '
                        f'{_num(m.gain_margin)} | {_num(m.phase_margin, ".1f")} | {_num(m.ms)} | '
                        f'{_num(m.mt)} | {_num(m.delay_margin)} | {_num(m.wc)} |')
    head = (f'{label}\n\n| loop | other loop | stable | GM | PM [deg] | Ms | Mt | '
            'delay margin [s] | crossover [rad/s] |\n|---|---|---|---|---|---|---|---|---|\n')
    return head + '\n'.join(rows) + '\n', out


def _no_loop_reason(sections: dict, controller_values: Mapping[str, Any] | None = None) -> str:
    from tank_control.core import scenario as core_scenario
    if controller_values is None:
        controller_values = core_scenario.node_values(sections, 'controller')
    try:
        _, reason = describe_loop(core_scenario.node_values(sections, 'plant'), controller_values)
    except (ValueError, ArithmeticError) as exc:
        reason = str(exc)
    return f'no loop to analyse: {reason}'


def _why_not(sections: dict, scenario_path: object) -> str:
    return f'{scenario_path}: {_no_loop_reason(sections)}\n'


def two_loop_key(row: Mapping[str, Any]) -> str:
    """A two-loop row's key in metrics.json ``loop_analysis``: the loop and the state of the
    other one, e.g. ``h (T_out closed)``."""
    return f'{row["loop"]} ({row["other_loop"]})'


def run_loop_analysis(sections: dict, controller_values: Mapping[str, Any]
                      ) -> dict[str, dict[str, object]] | str:
    """metrics.json ``loop_analysis`` of a run that has no SISO case: the two-loop PI's rows of
    ``tank-control analyze --json`` keyed by :func:`two_loop_key` (the same numbers, from the
    controller's final values), or the one line saying why there is no loop to analyse
    (MPCS)."""
    try:
        two = _two_loop(sections, controller_values)
        if two is not None:
            _, rows = _two_loop_table(*two)
            return {two_loop_key(row): {**row, 'model': two[1]} for row in rows}
        return _no_loop_reason(sections, controller_values)
    except (ValueError, KeyError, TypeError, ArithmeticError) as exc:
        return f'analysis.png not written: {exc}'


def plot_run_two_loop(sections: dict, controller_values: Mapping[str, Any], path: str | Path,
                      title: str = '') -> Path | None:
    """A run's ``analysis.png`` for the two-loop PI (:func:`plot_two_loop` of the controller's
    final values); None for another loop."""
    two = _two_loop(sections, controller_values)
    return plot_two_loop(two[0], path, title) if two is not None else None


def analyze(path: str | Path, overrides: tuple[str, ...] = (), plot: str | Path | None = None,
            as_json: bool = False) -> str:
    """The robustness table of a scenario file's controller on its plant model (and on the
    controller's own models), without running it: SISO loops of any kinds that describe
    themselves, and the mixing tank's two-loop PI per loop with the other loop open and closed.
    ``plot``: also draw :func:`plot_analysis` (SISO) there; ``as_json``: the numbers as strict
    JSON (an infinite margin, e.g. a phase that never reaches −180°, and an undefined one are
    null).
    A line saying why when there is nothing to analyse (e.g. MPCS)."""
    import json

    from tank_control.harness.runner import jsonable    # strict JSON: inf and NaN as null
    from tank_control.harness.scenario_file import load_scenario
    scenario = load_scenario(path, overrides)
    cases = loop_cases(scenario.sections)
    if cases:
        if plot is not None:
            plot_analysis(cases, plot, title=f'{Path(str(scenario.path)).name}: loop analysis')
        if as_json:
            return json.dumps(jsonable({'scenario': str(scenario.path),
                                        'loops': [_report_dict(c) for c in cases]}),
                              indent=2, allow_nan=False) + '\n'
        return robustness_table(cases)
    two = _two_loop(scenario.sections)
    if two is not None:
        analysis, label = two
        table, rows = _two_loop_table(analysis, label)
        if plot is not None:
            plot_two_loop(analysis, plot, title=f'{Path(str(scenario.path)).name}: two loops')
        if as_json:
            return json.dumps(jsonable({'scenario': str(scenario.path), 'two_loop': label,
                                        'loops': rows}), indent=2, allow_nan=False) + '\n'
        return table
    reason = _why_not(scenario.sections, scenario.path)
    if as_json:
        return json.dumps({'scenario': str(scenario.path), 'loops': [],
                           'reason': reason.strip()}, indent=2) + '\n'
    return reason


def plot_two_loop(analysis: TwoLoopAnalysis, path: str | Path, title: str = '') -> Path:
    """Bode magnitude and Nyquist of each loop of the two-loop PI with the other loop closed
    (solid, with its Ms circle) and open (dashed); the legend gives each one's Ms, PM and GM."""
    from tank_control.core.analysis.two_loop import LOOPS
    from tank_control.harness.plotting import plt, save_figure
    fig, (ax_mag, ax_nyq) = plt.subplots(1, 2, figsize=(13, 5.5))
    theta = np.linspace(0, 2 * math.pi, 200)
    for i, name in enumerate(LOOPS):
        for closed, style in ((True, '-'), (False, '--')):
            loop = analysis.loop(i, other_closed=closed)
            m = analysis.margins(i, other_closed=closed)
            w = fr.default_grid(loop)
            values = loop(w)
            other = f'{LOOPS[1 - i]} {"closed" if closed else "open"}'
            ax_mag.loglog(w, np.abs(values), style, color=f'C{i}', label=f'{name} ({other})')
            if math.isfinite(m.wc):
                ax_mag.axvline(m.wc, color=f'C{i}', ls=':', lw=0.8)
            ax_nyq.plot(values.real, values.imag, style, color=f'C{i}',
                        label=f'{name} ({other}): Ms {m.ms:.2f}, PM {m.phase_margin:.1f}°, '
                              f'GM {_num(m.gain_margin, ".2f")}')
            if closed:
                ax_nyq.plot(-1 + np.cos(theta) / m.ms, np.sin(theta) / m.ms, ':', color=f'C{i}',
                            lw=0.8)
    ax_mag.axhline(1.0, color='k', lw=0.6)
    ax_mag.set_xlabel('ω [rad/s]')
    ax_mag.set_ylabel('|L_i(jω)|')
    ax_mag.set_title('loop gains (other loop closed: solid, open: dashed)')
    ax_mag.legend(fontsize='small')
    ax_nyq.plot([-1], [0], 'k+', ms=10)
    ax_nyq.set_xlim(-3, 1.5)
    ax_nyq.set_ylim(-2.5, 2.0)
    ax_nyq.set_aspect('equal')
    ax_nyq.set_title('Nyquist, Ms circles of the closed cases ([Precup2013] eq. 3.7.4)')
    ax_nyq.legend(fontsize='small')
    for ax in (ax_mag, ax_nyq):
        _grid(ax)
    return save_figure(fig, Path(path), title, dpi=90)
