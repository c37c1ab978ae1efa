"""Tuning with a robustness target: realised Ms of the implemented discrete loop, load IAE and
setpoint overshoot of the Ms-constrained design ([Precup2013] §3.4.2 by optimisation) beside
Ziegler–Nichols, Cohen–Coon, AMIGO and SIMC on the same plants; and the cost of one live
robustness analysis.

Plants (gains 1, times in s): FOPDT T = 10, L/T in {0.1, 0.3, 1, 3}; IPDT k1 = 0.05 1/s, L = 5;
SOPDT T1 = 10, T2 = 5, L = 3. Sample time h = 0.1 s (every shipped scenario's), derivative
filter n = 10 (the PID's default). For each plant and each rule a PI and a PID:

* ``ms``          ``tune('ms', ..., ms=1.4 or 2.0, sample_time=h)``;
* ``zn``          classical Ziegler–Nichols from the model's exact ultimate point;
* ``cohen_coon``  FOPDT; on the SOPDT applied to the FOPDT of Skogestad's half rule
                  (T1 + T2/2, L + T2/2); none for the IPDT;
* ``amigo``; ``simc`` (τc = L; PID on the SOPDT only).

Columns: Ms of the implemented loop — the exact ZOH plant (``ProcessModel.response(h)``) times
``Pid2Dof``'s transfer function (``frequency.pid_feedback_discrete``) — from
``frequency.margins``, checked here against the largest |S| on a dense grid of 200 000 points up
to the Nyquist frequency; for ``ms`` its error against the target; the loop simulated with the
core objects (``robustness.predict``: ``Pid2Dof`` without limits on the project's plant of the
model, ``core/plants``) over the same window for every rule of a plant: IAE after a unit load
step at the plant input and overshoot after a unit setpoint step (the rule's setpoint weights
b, c; 1 where the rule gives none).

Timing: median wall time of one ``loop_report`` (what controller_node runs on every change of
the gains or the model, and what the ``robustness.ms_max`` guard runs on every proposed
change) on the shipped chain's FOPDT (K 0.05, T 10 s, L 3 s) with its Ms = 1.4 PID, and on the
SOPDT and the IPDT; the baseline in the same run is one ``Pid2Dof.update`` (one control
sample). Also the Ms design itself (``robust.ms_design``, uncached: what a change of
``autotune.rule`` or ``autotune.ms_target`` re-runs).

Usage: .venv/bin/python bench/bench_tuning.py [--repeats 15]
"""
from __future__ import annotations

import argparse
import math
import platform
import statistics
import time

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.robustness import horizon, loop_report, predict
from tank_control.core.control.pid import Pid2Dof, PidConfig
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.tuning.robust import ms_design
from tank_control.core.tuning.rules import tune

H = 0.1
N = 10.0
PLANTS = {
    'FOPDT L/T=0.1': ProcessModel('fopdt', 1.0, 1.0, 10.0),
    'FOPDT L/T=0.3': ProcessModel('fopdt', 1.0, 3.0, 10.0),
    'FOPDT L/T=1': ProcessModel('fopdt', 1.0, 10.0, 10.0),
    'FOPDT L/T=3': ProcessModel('fopdt', 1.0, 30.0, 10.0),
    'IPDT': ProcessModel('ipdt', 0.05, 5.0),
    'SOPDT': ProcessModel('sopdt', 1.0, 3.0, 10.0, 5.0),
}
TARGETS = (1.4, 2.0)
CHAIN = ProcessModel('fopdt', 0.05, 3.0, 10.0)


def designs(model: ProcessModel, kind: str) -> list[tuple[str, float | None, dict]]:
    """(rule label, Ms target or None, gains) of every rule that applies to the plant."""
    args = model.tune_arguments()
    out = [(f'ms {target}', target, tune('ms', kind, ms=target, sample_time=H, filter_n=N,
                                         **args)) for target in TARGETS]
    up = model.ultimate_point()
    out.append(('zn', None, tune('zn', kind, ku=up.ku, tu=up.tu)))
    if model.kind == 'fopdt':
        out.append(('cohen_coon', None, tune('cohen_coon', kind, **args)))
    elif model.kind == 'sopdt':                   # on the FOPDT of Skogestad's half rule
        half = dict(gain=model.gain, time_constant=model.time_constant + model.time_constant2 / 2,
                    dead_time=model.dead_time + model.time_constant2 / 2)
        out.append(('cohen_coon (half rule)', None, tune('cohen_coon', kind, **half)))
    for rule in ('amigo', 'simc'):
        try:
            out.append((rule, None, tune(rule, kind, **args)))
        except ValueError:
            pass                                  # no such design for this plant (SIMC PID)
    return out


def pid_config(g: dict) -> PidConfig:
    def given(key: str, default: float) -> float:
        return default if g.get(key) is None else float(g[key])
    return PidConfig(kp=float(g['kp']), ti=given('ti', math.inf) or math.inf,
                     td=given('td', 0.0), n=N, b=given('b', 1.0), c=given('c', 1.0),
                     sample_time=H)


def dense_ms(loop: fr.FrequencyResponse, w_low: float) -> float:
    """Largest |1/(1 + L)| on 200 000 log-spaced points from ``w_low`` to the Nyquist frequency."""
    w = np.logspace(math.log10(w_low), math.log10(math.pi / H * (1 - 1e-9)), 200_000)
    return float(np.max(np.abs(1.0 / (1.0 + loop(w)))))


def accuracy_table() -> tuple[str, float, float]:
    """The table; the largest |Ms error| of the ms designs [%] and the largest difference
    between ``margins``' Ms and the dense grid's [%]."""
    rows = ['| plant | kind | rule | kp | ti [s] | td [s] | b | Ms | Ms error [%] | IAE load | '
            'overshoot [%] |', '|---|---|---|---|---|---|---|---|---|---|---|']
    worst_err = worst_grid = 0.0
    for name, model in PLANTS.items():
        w_low = model.ultimate_point().wu / 1000.0
        cases = [(kind, *d) for kind in ('pi', 'pid') for d in designs(model, kind)]
        window = max(horizon(model, pid_config(g)) for *_, g in cases)
        for kind, rule, target, g in cases:
            cfg = pid_config(g)
            loop = fr.pid_feedback_discrete(cfg.kp, cfg.ti, cfg.td, N, sample_time=H) \
                * model.response(H)
            stable = fr.closed_loop_stable(loop)
            ms = fr.margins(loop).ms
            if stable:
                worst_grid = max(worst_grid, abs(dense_ms(loop, w_low) / ms - 1.0) * 100.0)
            err = ''
            if target is not None:
                e = (ms / target - 1.0) * 100.0
                worst_err = max(worst_err, abs(e))
                err = f'{e:+.2f}'
            if stable:
                p = predict(model, cfg, duration=window)
                sim = f'{p.iae_load:.4g} | {p.overshoot:.1f}'
            else:
                sim = 'unstable | unstable'
            ti = f'{cfg.ti:.4g}' if math.isfinite(cfg.ti) else '-'
            rows.append(f'| {name} | {kind.upper()} | {rule} | {cfg.kp:.4g} | {ti} | '
                        f'{cfg.td:.4g} | {cfg.b:.3g} | {ms:.3f}{"" if stable else " (unstable)"} '
                        f'| {err} | {sim} |')
    return '\n'.join(rows), worst_err, worst_grid


def median_time(fn, repeats: int, inner: int = 1) -> float:
    """Median over ``repeats`` of the mean wall time of ``inner`` calls [s]."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(inner):
            fn()
        times.append((time.perf_counter() - t0) / inner)
    return statistics.median(times)


def timing(repeats: int) -> str:
    pid = Pid2Dof(PidConfig(kp=1.0, ti=10.0, td=1.0, sample_time=H))
    base = median_time(lambda: pid.update(1.0, 0.5), repeats, inner=2000)
    lines = [f'baseline: one `Pid2Dof.update` (one control sample): {base * 1e6:.2f} µs', '',
             '| what | model | median [ms] | ratio to one control sample |', '|---|---|---|---|']
    for label, model in (('shipped chain FOPDT', CHAIN), ('SOPDT', PLANTS['SOPDT']),
                         ('IPDT', PLANTS['IPDT'])):
        cfg = pid_config(tune('ms', 'pid', ms=1.4, sample_time=H, filter_n=N,
                              **model.tune_arguments()))
        t_rep = median_time(lambda: loop_report(model, cfg), repeats)
        lines.append(f'| `loop_report` (live robustness.*, the ms_max guard) | {label} '
                     f'({model.describe()}) | {t_rep * 1e3:.1f} | {t_rep / base:.0f} |')
        t_des = median_time(lambda: ms_design(model, 'pid', 1.4, None, H, N),
                            max(3, repeats // 3))
        lines.append(f'| Ms = 1.4 PID design, `ms_design` (a rule/target change) | {label} '
                     f'| {t_des * 1e3:.0f} | {t_des / base:.0f} |')
    return '\n'.join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=15)
    args = parser.parse_args()
    print(f'python {platform.python_version()}, numpy {np.__version__}, '
          f'{platform.machine()}, load average {" ".join(f"{x:.2f}" for x in _load())}')
    print(f'h = {H} s, n = {N:g}; Ms of the implemented discrete loop (exact ZOH plant × Pid2Dof)\n')
    table, worst_err, worst_grid = accuracy_table()
    print(table)
    print(f'\nlargest |Ms error| of the ms designs: {worst_err:.3f} %; largest difference '
          f'between margins() and a 200 000-point grid: {worst_grid:.4f} %\n')
    print(timing(args.repeats))


def _load() -> tuple[float, ...]:
    try:
        import os
        return os.getloadavg()
    except OSError:
        return (math.nan,) * 3


if __name__ == '__main__':
    main()
