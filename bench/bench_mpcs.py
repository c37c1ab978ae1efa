"""MPCS benchmarks: per-sample time of the analytic and QP versions at the default horizons
and at [Michalski2021]'s (100, 50) (the baseline, measured in the same run), the QP library comparison,
a one-hour tank scenario run in-process, design rebuild times and IAE.

    .venv/bin/python bench/bench_mpcs.py [--runs 3] [--quick]

QP problems are recorded along a closed-loop run on the nonlinear tank (setpoint
steps on h and T, an F_D step; re-linearisation off so that H and the constraint
matrix stay fixed) so that the rate limits are active in the transients, then replayed on
each library (same H, f, bounds) to compare the solvers on identical data. Results go to stdout as Markdown; copy them to
bench/RESULTS.md.
"""
from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import numpy as np

from tank_control.core.control.mpcs import Mpcs, MpcsConfig
from tank_control.core.plants.mixing_tank import MixingTank

DOCUMENT = (100, 50, 1)     # [Michalski2021] §6 (N, Nu, block): the baseline of the timing tables


class _Tank(MixingTank):
    """The nonlinear tank (core/plants); ``d = [F_D, T_D]`` as MPCS measures them."""

    def step(self, u, d, dt):
        super().step(u, [d[0], d[1], 62.0, 23.0], dt)


def make_tank() -> MixingTank:
    return _Tank()


def reference(t: float) -> np.ndarray:
    """Setpoints [h cm, T_out °C]: h 81→85 at 100 s, T 33.57→36 at 1500 s, h→78 at 2400 s."""
    r = np.array([81.0, 2115.0 / 63.0])
    if t >= 100:
        r[0] = 85.0
    if t >= 1500:
        r[1] = 36.0
    if t >= 2400:
        r[0] = 78.0
    return r


def disturbance(t: float) -> np.ndarray:
    """[F_D cm³/s, T_D °C]: F_D 12→16 at 2800 s, →10 at 3300 s."""
    f_d = 12.0 if t < 2800 else (16.0 if t < 3300 else 10.0)
    return np.array([f_d, 33.0])


def run_loop(cfg: MpcsConfig | None, samples: int, record: bool = False, controller=None):
    """Closed loop; returns (per-step seconds, wall seconds, recorded QPs, controller, IAE)."""
    ctl = controller if controller is not None else Mpcs(cfg)
    plant = make_tank()
    u = np.array([14.0, 37.0])
    ctl.reset(plant.outputs(), u)
    recorded = []
    design = getattr(ctl, '_design', None)
    if record and design is not None and design.qp is not None:   # keep the QP data
        qp = ctl._design.qp
        solve = qp.solve

        def keep(f, lb, ub, lo, hi):
            res = solve(f, lb, ub, lo, hi)
            recorded.append((f.copy(), lb.copy(), ub.copy(), lo.copy(), hi.copy(),
                             None if res.x is None else res.x.copy()))
            return res
        qp.solve = keep
    steps = []
    iae = np.zeros(2)
    start = time.perf_counter()
    for k in range(samples):
        t = float(k)
        y = plant.outputs()
        d = disturbance(t)
        r = reference(t)
        a = time.perf_counter()
        u = ctl.step(t, y, r, d)
        steps.append(time.perf_counter() - a)
        iae += np.abs(r - y)
        plant.step(u, d, 1.0)
    wall = time.perf_counter() - start
    return np.array(steps), wall, recorded, ctl, iae


# --- QP libraries, each set up once and fed the recorded (f, bounds) ---------------------
def lib_daqp_warm(h, a, problems):
    import daqp
    model, out, times = None, [], []
    for f, lb, ub, lo, hi, _ in problems:
        upper = np.clip(np.concatenate([ub, hi]), -1e20, 1e20)
        lower = np.clip(np.concatenate([lb, lo]), -1e20, 1e20)
        s = time.perf_counter()
        if model is None:
            model = daqp.Model()
            model.setup(h, f, a, upper, lower)
        else:
            model.update(f=f, bupper=upper, blower=lower)
        x, _, flag, _ = model.solve()
        times.append(time.perf_counter() - s)
        out.append(np.asarray(x))
    return times, out


def lib_daqp_cold(h, a, problems):
    import daqp
    out, times = [], []
    for f, lb, ub, lo, hi, _ in problems:
        upper = np.clip(np.concatenate([ub, hi]), -1e20, 1e20)
        lower = np.clip(np.concatenate([lb, lo]), -1e20, 1e20)
        s = time.perf_counter()
        x, _, flag, _ = daqp.solve(h, f, a, upper, lower)
        times.append(time.perf_counter() - s)
        out.append(np.asarray(x))
    return times, out


def lib_quadprog(h, a, problems):
    import quadprog
    n = h.shape[0]
    eye = np.eye(n)
    c = np.hstack([eye, -eye, a.T, -a.T])            # Cᵀ x ≥ b
    out, times = [], []
    for f, lb, ub, lo, hi, _ in problems:
        b = np.concatenate([np.clip(lb, -1e20, 1e20), -np.clip(ub, -1e20, 1e20),
                            np.clip(lo, -1e20, 1e20), -np.clip(hi, -1e20, 1e20)])
        s = time.perf_counter()
        x = quadprog.solve_qp(h, -f, c, b, 0)[0]
        times.append(time.perf_counter() - s)
        out.append(x)
    return times, out


def lib_proxsuite(h, a, problems):
    from proxsuite import proxqp
    n, m = h.shape[0], a.shape[0]
    qp = proxqp.dense.QP(n, 0, m, True)
    qp.settings.eps_abs = 1e-8
    qp.settings.initial_guess = proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
    out, times = [], []
    first = True
    for f, lb, ub, lo, hi, _ in problems:
        s = time.perf_counter()
        if first:
            qp.init(h, f, None, None, a, lo, hi, lb, ub)
            first = False
        else:
            qp.update(g=f, l=lo, u=hi, l_box=lb, u_box=ub)
        qp.solve()
        times.append(time.perf_counter() - s)
        out.append(np.array(qp.results.x))
    return times, out


def lib_osqp(h, a, problems):
    import osqp
    from scipy import sparse
    n = h.shape[0]
    a_full = sparse.csc_matrix(np.vstack([np.eye(n), a]))
    p = sparse.csc_matrix(np.triu(h))
    solver = None
    out, times = [], []
    for f, lb, ub, lo, hi, _ in problems:
        lower = np.concatenate([lb, lo])
        upper = np.concatenate([ub, hi])
        s = time.perf_counter()
        if solver is None:
            solver = osqp.OSQP()
            solver.setup(p, f, a_full, lower, upper, verbose=False, warm_starting=True,
                         eps_abs=1e-7, eps_rel=1e-7, polishing=False, max_iter=20000)
        else:
            solver.update(q=f, l=lower, u=upper)
        res = solver.solve()
        times.append(time.perf_counter() - s)
        out.append(np.asarray(res.x))
    return times, out


LIBS = {'daqp (warm, Model)': lib_daqp_warm, 'daqp (cold)': lib_daqp_cold,
        'quadprog': lib_quadprog, 'proxsuite (warm)': lib_proxsuite, 'osqp (warm)': lib_osqp}


def ms(values) -> str:
    v = np.asarray(values) * 1e3
    return f'{np.median(v):.3f} | {np.percentile(v, 99):.3f}'


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--samples', type=int, default=3600)
    parser.add_argument('--quick', action='store_true', help='fewer samples, one run')
    args = parser.parse_args()
    samples = 600 if args.quick else args.samples
    runs = 1 if args.quick else args.runs
    base = MpcsConfig()
    print(f'## MPCS per-sample times ({samples} samples of the tank scenario, '
          f'median over {runs} runs of each statistic), ms\n')
    print('| controller | (N, Nu, block) | decision variables | step median | step p99 | '
          'solver fallbacks |')
    print('|---|---|---|---|---|---|')
    default = (base.horizon, base.control_horizon, base.block)
    cases = [('analytic', *DOCUMENT), ('analytic', *default), ('qp', *DOCUMENT),
             ('qp', *default), ('qp', default[0], default[1], 1)]
    recorded = {}
    for solver, n, nu, block in cases:
        cfg = replace(base, solver=solver, horizon=n, control_horizon=nu, block=block)
        meds, p99s, fb = [], [], 0
        for run in range(runs):
            steps, _, _, ctl, _ = run_loop(cfg, samples)
            meds.append(np.median(steps) * 1e3)
            p99s.append(np.percentile(steps, 99) * 1e3)
            fb = ctl.status['fallbacks']
        if solver == 'qp' and (n, nu, block) in (DOCUMENT, default):   # library comparison
            fixed = replace(cfg, relinearize=False)
            _, _, rec, ctl, _ = run_loop(fixed, samples, record=True)
            recorded[(n, nu, block)] = (ctl._design.qp.h, ctl._design.qp.a, rec)
        n_dec = 2 * -(-nu // block)
        print(f'| MPCS-{solver} | ({n}, {nu}, {block}) | {n_dec} | '
              f'{statistics.median(meds):.3f} | {statistics.median(p99s):.3f} | {fb} |')
    print('\n## QP library comparison (same recorded QPs, solve call only), ms\n')
    print('| (N, Nu, block) | library | median | p99 | max |x − x_daqp| |')
    print('|---|---|---|---|---|')
    for (n, nu, block), (h, a, rec) in recorded.items():
        ref = [r[5] for r in rec]
        for name, fn in LIBS.items():
            try:
                times, xs = fn(h, a, rec)
            except Exception as exc:  # noqa: BLE001 - report and continue
                print(f'| ({n}, {nu}, {block}) | {name} | failed: {exc} | | |')
                continue
            err = max(float(np.max(np.abs(x - r))) for x, r in zip(xs, ref) if r is not None)
            print(f'| ({n}, {nu}, {block}) | {name} | {ms(times)} | {err:.1e} |')
    print('\n## One-hour tank scenario in-process, MPCS-QP, wall time, s\n')
    print('| (N, Nu, block) | median | runs | fallbacks |')
    print('|---|---|---|---|')
    for n, nu, block in (DOCUMENT, default):
        walls = []
        for _ in range(runs):
            _, wall, _, ctl, _ = run_loop(replace(base, solver='qp', horizon=n,
                                                  control_horizon=nu, block=block), 3600)
            walls.append(wall)
        print(f'| ({n}, {nu}, {block}) | {statistics.median(walls):.2f} | '
              f'{", ".join(f"{w:.2f}" for w in walls)} | {ctl.status["fallbacks"]} |')
    print('\n## Design (re)build time, ms (median of runs)\n')
    print('| (N, Nu, block) | construct | configure(horizon) | configure(operating point) |')
    print('|---|---|---|---|')
    for n, nu, block in (DOCUMENT, default):
        rows = []
        for _ in range(runs):
            a = time.perf_counter()
            ctl = Mpcs(replace(base, solver='qp', horizon=n, control_horizon=nu, block=block))
            b = time.perf_counter()
            ctl.configure(horizon=n + 1)
            c = time.perf_counter()
            ctl.configure(op_F_H=15.0)
            rows.append((b - a, c - b, time.perf_counter() - c))
        med = [statistics.median(col) * 1e3 for col in zip(*rows)]
        print(f'| ({n}, {nu}, {block}) | {med[0]:.0f} | {med[1]:.0f} | {med[2]:.0f} |')
    print('\n## IAE on the one-hour scenario (h [cm·s], T_out [°C·s])\n')
    print('| controller | IAE h | IAE T_out |')
    print('|---|---|---|')
    doc = replace(base, horizon=DOCUMENT[0], control_horizon=DOCUMENT[1], block=DOCUMENT[2])
    for label, cfg in ((f'MPCS analytic {default}, λ 0.5', replace(base, solver='analytic')),
                       (f'MPCS qp {default}, λ 0.5', replace(base, solver='qp')),
                       (f'MPCS qp {default}, no re-linearisation',
                        replace(base, solver='qp', relinearize=False)),
                       (f'MPCS analytic {DOCUMENT}, λ 0.5', replace(doc, solver='analytic')),
                       (f'MPCS qp {DOCUMENT}, λ 0.5', replace(doc, solver='qp')),
                       (f"MPCS qp {DOCUMENT}, document's cost (align off, w_∞ = 0)",
                        replace(doc, solver='qp', align=False, terminal_weight=0.0))):
        iae = run_loop(cfg, 3600)[4]
        print(f'| {label} | {iae[0]:.0f} | {iae[1]:.0f} |')
    try:
        from tank_control.core.control.multiloop import TwoLoopPi, document_config
    except ImportError:
        print('| two-loop PI ([Michalski2021] §2) | not available in this checkout | |')
    else:
        for dec in ('none', 'static'):
            iae = run_loop(None, 3600, controller=TwoLoopPi(document_config(dec)))[4]
            print(f'| two-loop PI of [Michalski2021], decoupling {dec} | {iae[0]:.0f} | {iae[1]:.0f} |')


if __name__ == '__main__':
    main()
