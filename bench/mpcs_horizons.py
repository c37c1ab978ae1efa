"""MPCS horizons against the tank's dead times: the measurements behind the default
(N, Nu, block) and behind ``mpcs.horizon_warning`` (docs/mpcs.md, "Horizons").

    .venv/bin/python bench/mpcs_horizons.py [--quick]

1. The document's sequence (config/scenarios/tank_mpcs_qp_003.yaml: h, T_out and F_D
   changes 1500 s apart, 9100 s, nonlinear tank, 0 <= u <= 100, |du| <= 0.2), in-process,
   for several horizons x output weights x lambda: the worst |e_h| [cm] and |e_T| [°C] from
   1200 s after each change to the next (the claim: <= 0.05 cm, <= 0.02 °C), the level
   error 1200 s after the first change (h 81 -> 90 cm at 100 s) and the whole-run IAE.
2. The nominal loop (plant = the controller's own linear model with its dead times, exact
   state, unconstrained analytic move): the slowest closed-loop time constant [s] and the
   time after a 9 cm level step until |e_h| <= 0.05 cm and |e_T| <= 0.02 °C for good —
   which direction is slow, without the nonlinearity or the rate limits.

Prints Markdown tables (stdout). Times are simulated seconds; nothing here is a speed
measurement (bench_mpcs.py is).
"""
from __future__ import annotations

import argparse
import copy
import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np

from tank_control.core.control.mpcs import MpcsConfig, _Design, horizon_warning
from tank_control.core import params_file
from tank_control.core.scenario import run_in_process

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / 'config' / 'scenarios' / 'tank_mpcs_qp_003.yaml'
SETTLED = 1200.0          # [s] after a change: from here to the next change the claim holds
DOCUMENT = (100, 50, 1)   # [Michalski2021] §6 (N, Nu, block)
ISSUE = (400, 50, 1)      # a longer N alone
DEFAULT = (MpcsConfig().horizon, MpcsConfig().control_horizon, MpcsConfig().block)


def changes(reference: dict) -> list[float]:
    return sorted({float(t) for k, v in reference.items() if k.endswith('.times')
                   for t in v if t > 0})


def scenario_run(horizons: tuple[int, int, int], weights=(1.0, 1.0), lam=0.5,
                 **extra) -> dict[str, float]:
    """One in-process run of the document's sequence; errors [cm], [°C], IAE."""
    params = copy.deepcopy(params_file.read(SCENARIO))
    n, nu, block = horizons
    params['controller'].update({'mpcs.horizon': n, 'mpcs.control_horizon': nu,
                                 'mpcs.block': block, 'mpcs.output_weights': list(weights),
                                 'mpcs.lambda': [lam], **extra})
    trace = run_in_process(params)
    t = trace['t']
    cs = changes(params['reference'])
    ends = cs[1:] + [float(t[-1]) + 1.0]
    e = {o: np.abs(trace[f'r.{o}'] - trace[f'y.{o}']) for o in ('h', 'T_out')}
    worst = {o: max(float(e[o][(t >= c + SETTLED) & (t < end)].max()) for c, end in zip(cs, ends))
             for o in e}
    k = int(np.searchsorted(t, cs[0] + SETTLED))
    return {'e_h': worst['h'], 'e_T': worst['T_out'],
            'e_h_1200': float(trace['y.h'][k] - trace['r.h'][k]),
            'iae_h': float(np.trapezoid(e['h'], t)), 'iae_T': float(np.trapezoid(e['T_out'], t))}


def nominal(cfg: MpcsConfig, samples: int = 4000) -> tuple[float, int]:
    """(slowest closed-loop time constant [s], settling [s] of a 9 cm level step) of the
    unconstrained move on the controller's own linear delayed model."""
    des = _Design(cfg)
    pred, model, sys = des.pred, des.model, des.estimator.sys
    n_xi, n_buf = sys.n, sum(model.input_delays)
    slow = int(np.argmax(model.input_delays))

    def step(v: np.ndarray, r: np.ndarray) -> np.ndarray:
        xi, bufs, u_prev = v[:n_xi], v[n_xi:n_xi + n_buf], v[n_xi + n_buf:]
        z = np.concatenate([xi, bufs, u_prev, np.zeros(model.n_d)])
        u = u_prev + pred.k_r @ r - pred.k_z @ z
        u_eff = u.copy()
        u_eff[slow] = bufs[0]
        return np.concatenate([sys.a @ xi + sys.b_u @ u_eff, bufs[1:], [u[slow]], u])

    size = n_xi + n_buf + model.n_u
    a_cl = np.column_stack([step(e, np.zeros(2)) for e in np.eye(size)])
    b_cl = np.column_stack([step(np.zeros(size), e) for e in np.eye(2)])
    eig = np.linalg.eigvals(a_cl)
    eig = eig[np.abs(eig - 1.0) > 1e-9]          # the disturbance integrators (not excited)
    tau = -cfg.sample_time / np.log(np.max(np.abs(eig)))
    v, r, last_bad = np.zeros(size), np.array([9.0, 0.0]), 0
    for k in range(samples):
        e = sys.c @ v[:n_xi] - r
        if abs(e[0]) > 0.05 or abs(e[1]) > 0.02:
            last_bad = k + 1
        v = a_cl @ v + b_cl @ r
    return float(tau), last_bad


def fmt_h(h: tuple[int, int, int]) -> str:
    return f'({h[0]}, {h[1]}, {h[2]})'


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--quick', action='store_true', help='fewer scenario runs')
    args = parser.parse_args()
    base = MpcsConfig()
    print(f'Default (N, Nu, block) = {fmt_h(DEFAULT)}; warning for the defaults: '
          f'{horizon_warning(base) or "none"}')
    print(f'Warning for [Michalski2021] §6 (100, 50, 1): '
          f'{horizon_warning(replace(base, horizon=100, control_horizon=50, block=1))}\n')

    print('## 1. Document sequence (tank_mpcs_qp_003.yaml), QP, nonlinear tank, in-process\n')
    print('| (N, Nu, block) | W_y (h, T) | λ | other | worst settled \\|e_h\\| cm | worst settled '
          '\\|e_T\\| °C | e_h 1200 s after the h step, cm | IAE h | IAE T | claim |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    rows = [(DOCUMENT, (1.0, 1.0), 0.5, {}), (DOCUMENT, (1.0, 30.0), 0.5, {}),
            (ISSUE, (1.0, 1.0), 0.5, {}), (ISSUE, (1.0, 30.0), 0.5, {}),
            (ISSUE, (30.0, 1.0), 0.5, {}), (ISSUE, (1.0, 100.0), 0.5, {}),
            (DEFAULT, (1.0, 1.0), 0.5, {}), (DEFAULT, (1.0, 30.0), 0.5, {}),
            (DEFAULT, (30.0, 1.0), 0.5, {}), (DEFAULT, (1.0, 100.0), 0.5, {}),
            (DEFAULT, (100.0, 1.0), 0.5, {})]
    if not args.quick:
        rows += [(DOCUMENT, (1.0, 1.0), 0.5, {'mpcs.terminal_weight': 0.0}),
                 (DOCUMENT, (1.0, 1.0), 0.5, {'mpcs.align': False}),
                 (DOCUMENT, (30.0, 1.0), 0.5, {}),
                 ((600, 100, 10), (1.0, 100.0), 0.5, {}),
                 ((600, 100, 10), (100.0, 1.0), 0.5, {}),
                 ((600, 200, 20), (1.0, 100.0), 0.5, {}),
                 (DEFAULT, (1.0, 1.0), 0.1, {}), (DEFAULT, (1.0, 1.0), 10.0, {}),
                 (DEFAULT, (1.0, 30.0), 10.0, {}), (DEFAULT, (30.0, 1.0), 10.0, {}),
                 (DEFAULT, (1.0, 1.0), 0.5, {'mpcs.solver': 'analytic'}),
                 (DEFAULT, (1.0, 30.0), 0.5, {'mpcs.solver': 'analytic'})]
    for horizons, weights, lam, extra in rows:
        m = scenario_run(horizons, weights, lam, **extra)
        ok = m['e_h'] <= 0.05 and m['e_T'] <= 0.02
        other = ', '.join(f'{k.removeprefix("mpcs.")} {v}' for k, v in extra.items()) or ''
        print(f'| {fmt_h(horizons)} | {weights[0]:g}, {weights[1]:g} | {lam:g} | {other} | '
              f'{m["e_h"]:.3f} | {m["e_T"]:.4f} | {m["e_h_1200"]:+.3f} | {m["iae_h"]:.0f} | '
              f'{m["iae_T"]:.0f} | {"met" if ok else "**not met**"} |', flush=True)

    print('\n## 2. Nominal linear loop, unconstrained: slowest closed-loop time constant [s] / '
          'settling of a 9 cm level step [s]\n')
    weights = [(1.0, 1.0), (1.0, 30.0), (30.0, 1.0), (1.0, 100.0)]
    print('| (N, Nu, block) | λ | w_∞ | ' + ' | '.join(f'W_y {w[0]:g}, {w[1]:g}' for w in weights)
          + ' |')
    print('|---|---|---|' + '---|' * len(weights))
    horizons = [DOCUMENT, ISSUE, (600, 50, 1), (600, 100, 10), (600, 181, 10), (600, 191, 10),
                DEFAULT, (600, 200, 20), (200, 200, 10), (300, 200, 10), (472, 200, 10)]
    cases = [(h, 0.5, 100.0) for h in horizons]
    if not args.quick:
        cases += [(h, lam, tw) for lam, tw in itertools.product((100.0, 1000.0), (0.0, 100.0))
                  for h in ((200, 200, 10), (300, 200, 10), (400, 200, 10), (472, 200, 10),
                            DEFAULT, (1000, 200, 10))]
    for (n, nu, block), lam, tw in cases:
        cells = []
        for w in weights:
            cfg = replace(base, horizon=n, control_horizon=nu, block=block, output_weights=w,
                          lam=(lam,), terminal_weight=tw)
            tau, settle = nominal(cfg)
            cells.append(f'{tau:.0f} / {settle}')
        print(f'| {fmt_h((n, nu, block))} | {lam:g} | {tw:g} | ' + ' | '.join(cells) + ' |',
              flush=True)
    model = _Design(base).model
    tau_open = [-1.0 / np.log(abs(x)) for x in np.linalg.eigvals(model.a)]
    print(f'\nOpen-loop time constants of the model at h0 = 81 cm: '
          f'{", ".join(f"{t:.1f}" for t in sorted(tau_open))} s (T, h).')


if __name__ == '__main__':
    main()
