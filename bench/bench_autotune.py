"""Relay auto-tuning accuracy: describing function vs first harmonic ([DeadTimeNotes] §1.3, [Precup2013] §3.2–3.3).

For FOPDT (K = 1, T = 1, L/T in {0.1, 0.3, 1, 3}), IPDT (k1 = 0.05, To = 5) and, outside
the model family, 1/(s+1)²·e^(−L·s) (L = 0.3, 1), a relay of amplitude d = 1 runs on the
exact plant (fractional dead time, ZOH), sampled with
``--spp`` samples per ultimate period; measurement noise is white with σ = noise·a
(a = output amplitude of the ideal relay), hysteresis ε = 4σ. Four stationary cycles
(after the first) are analysed by ``identify_relay``. Errors against the exact ultimate
point (solved here from the phase condition) are given as median and worst absolute
value over ``--seeds`` noise seeds, in per cent:

* DF   — describing function 4d/(π·a) with the hysteresis correction, period of the cycles
* FH   — first harmonic 1/|Y1/U1| at ωc, uncorrected
* FH+M — first harmonic corrected to the −180° point along the FOPDT/IPDT model fitted in
         the time domain
* FH+L — first harmonic corrected along the local model k·e^(−Ls)/(s+α)^n through G(jωc)
         and G(j3ωc) (n real; falls back to FH+M when it has no solution): used by the tuner

Usage: .venv/bin/python bench/bench_autotune.py [--seeds 10] [--spp 47.3] [--closed-loop]
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from scipy.linalg import expm

from tank_control.core.tuning.identification import identify_relay, relay_cycles


# plant: (A, B, C) delay-free part, dead time L; y = C·x
PLANTS = {
    0.1: ('FOPDT', [[-1.0]], [1.0], [1.0], 0.1),
    0.3: ('FOPDT', [[-1.0]], [1.0], [1.0], 0.3),
    1.0: ('FOPDT', [[-1.0]], [1.0], [1.0], 1.0),
    3.0: ('FOPDT', [[-1.0]], [1.0], [1.0], 3.0),
    'ipdt': ('IPDT', [[0.0]], [0.05], [1.0], 5.0),
    # outside the FOPDT/IPDT family: 1/(s+1)^2·e^(-L·s)
    'sopdt0.3': ('SOPDT', [[-1.0, 0.0], [1.0, -1.0]], [1.0, 0.0], [0.0, 1.0], 0.3),
    'sopdt1': ('SOPDT', [[-1.0, 0.0], [1.0, -1.0]], [1.0, 0.0], [0.0, 1.0], 1.0),
}


def exact_ultimate(case: float | str) -> tuple[float, float]:
    """Ultimate point solved from the phase condition: ω·L + n·arctan(ω) = π (n = 1, 2), IPDT closed form."""
    kind, *_, dead = PLANTS[case]
    if kind == 'IPDT':
        return math.pi / (2 * 0.05 * dead), 4 * dead
    n = 2 if kind == 'SOPDT' else 1
    lo, hi = 0.0, math.pi / dead
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if mid * dead + n * math.atan(mid) < math.pi else (lo, mid)
    return (1 + lo * lo) ** (n / 2), 2 * math.pi / lo


def _zoh(a: np.ndarray, b: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH step of length h: x ← Φ·x + Γ·u (augmented matrix exponential)."""
    n = a.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n], m[:n, n] = a * h, b * h
    e = expm(m)
    return e[:n, :n], e[:n, n]


def relay_run(case: float | str, noise: float, seed: int, spp: float, periods: int = 6):
    """Relay loop on the exact sampled plant: within each sample the delayed ZOH input
    changes once, at the fractional delay, so two exact ZOH steps per sample."""
    _, a, b, c, dead = PLANTS[case]
    a, b, c = np.array(a), np.array(b), np.array(c)
    d = 1.0
    ku, tu = exact_ultimate(case)
    ts = tu / spp
    n_delay = int(dead // ts)
    frac = dead - n_delay * ts
    phi1, gam1 = _zoh(a, b, frac)
    phi2, gam2 = _zoh(a, b, ts - frac)
    # output amplitude of the ideal relay, for the noise level (from a noise-free run)
    amp = None
    if noise > 0:
        _, _, y0, _ = relay_run(case, 0.0, 0, spp, periods)
        amp = 0.5 * (y0[len(y0) // 2:].max() - y0[len(y0) // 2:].min())
    sigma = noise * amp if amp else 0.0
    eps = 4 * sigma
    rng = np.random.default_rng(seed)
    samples = int(periods * spp)
    hist = np.zeros(samples + n_delay + 2)      # applied inputs, index offset n_delay + 1
    t, u, y = np.arange(samples) * ts, np.zeros(samples), np.zeros(samples)
    x, high = np.zeros(a.shape[0]), True
    for k in range(samples):
        y[k] = c @ x + sigma * rng.standard_normal()
        if -y[k] > eps:
            high = True
        elif -y[k] < -eps:
            high = False
        u[k] = d if high else -d
        hist[k + n_delay + 1] = u[k]
        x = phi1 @ x + gam1 * hist[k]           # [t_k, t_k + frac): input of sample k - n_delay - 1
        x = phi2 @ x + gam2 * hist[k + 1]       # [t_k + frac, t_k+1): input of sample k - n_delay
    return t, u, y, eps


def closed_loop_run(case: float | str, seed: int) -> tuple[float, float, float, str]:
    """The whole RelayAutotuner (settling, auto hysteresis, relay, fit, ZN PI) on core/plants
    Fopdt (K = 2, T = 5, L = ratio·T; '[DeadTimeNotes]': K = 0.05, T = 10, L = 3) or Ipdt (k1 = 0.05,
    To = 5) at rest, noise 1 % of the relay output amplitude, 50 samples per Tu.
    Returns (Ku error %, Tu error %, relay start → tuned in periods Tu, final state)."""
    from tank_control.core.control.pid import PidConfig
    from tank_control.core.control.relay_autotune import AutotuneConfig, RelayAutotuner
    from tank_control.core.plants.fopdt import Fopdt, FopdtConfig
    from tank_control.core.plants.ipdt import Ipdt, IpdtConfig
    if case == 'ipdt':
        k1, dead = 0.05, 5.0
        plant = Ipdt(IpdtConfig(gain=k1, dead_time=dead, initial_output=10.0))
        ku, tu = math.pi / (2 * k1 * dead), 4 * dead
        d, amp, pid = 1.0, k1 * dead, dict(kp=0.2 / (k1 * dead), ti=40.0)
    else:
        gain, tc, dead = (0.05, 10.0, 3.0) if case == '[DeadTimeNotes]' else (2.0, 5.0, 5.0 * float(case))
        plant = Fopdt(FopdtConfig(gain=gain, time_constant=tc, dead_time=dead, initial_output=10.0))
        lo, hi = 0.0, math.pi / dead
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if mid * dead + math.atan(mid * tc) < math.pi else (lo, mid)
        ku, tu = math.sqrt(1 + (lo * tc) ** 2) / gain, 2 * math.pi / lo
        d = 200.0 if case == '[DeadTimeNotes]' else 1.0
        amp, pid = gain * d * (1 - math.exp(-dead / tc)), dict(kp=0.2 * ku, ti=tc + dead)
    ts = tu / 50
    tuner = RelayAutotuner(PidConfig(sample_time=ts, **pid),
                           AutotuneConfig(relay_amplitude=d, settle_time=10 * ts, settle_band=0.2 * amp,
                                          timeout=20 * tu, rule='zn_001', kind='pi'))
    tuner.reset(np.array([10.0]), np.array([0.0]))
    rng = np.random.default_rng(seed)
    t_relay = t_tuned = math.nan
    for k in range(int(14 * tu / ts)):
        t = k * ts
        if k == 5:
            tuner.start()
        y = plant.outputs() + 0.01 * amp * rng.standard_normal(1)
        u = tuner.step(t, y, np.array([10.0]), np.zeros(0))
        if tuner.state == 'relay' and math.isnan(t_relay):
            t_relay = t
        if tuner.state == 'tuned':
            t_tuned = t
        plant.step(u, np.zeros(1), ts)
    st = tuner.status
    return 100 * (st['ku'] / ku - 1), 100 * (st['tu'] / tu - 1), (t_tuned - t_relay) / tu, st['state']


def closed_loop_table(seeds: int) -> None:
    print(f'\nRelayAutotuner closed loop on core/plants, 1 % noise, 50 samples per Tu, {seeds} seeds: '
          'worst |error| in %, experiment length (relay start → tuned PID) in Tu')
    print(f"{'plant':>12} | {'Ku':>6} {'Tu':>6} | {'periods':>7} | all running")
    for case in (0.1, 0.3, 1.0, 3.0, 'ipdt', '[DeadTimeNotes]'):
        runs = [closed_loop_run(case, seed) for seed in range(seeds)]
        e = np.array([r[:3] for r in runs])
        name = {'ipdt': 'IPDT', '[DeadTimeNotes]': '[DeadTimeNotes] example'}.get(case, f'FOPDT L/T={case}')
        print(f'{name:>12} | {np.abs(e[:, 0]).max():6.2f} {np.abs(e[:, 1]).max():6.2f} | '
              f'{e[:, 2].max():7.2f} | {all(r[3] == "running" for r in runs)}')


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--spp', type=float, default=47.3)
    parser.add_argument('--closed-loop', action='store_true',
                        help='also run the whole RelayAutotuner on core/plants over the seeds')
    args = parser.parse_args()
    cases = list(PLANTS)
    print(f'samples per period {args.spp:g}, seeds {args.seeds}, 4 stationary cycles; '
          'errors in % (median / worst |error|)')
    head = (f"{'plant':>12} {'noise':>6} | {'DF ku':>13} {'DF tu':>13} | {'FH ku':>13} {'FH tu':>13} |"
            f" {'FH+M ku':>13} {'FH+M tu':>13} | {'FH+L ku':>13} {'FH+L tu':>13} | {'ms/ident':>8}")
    print(head)
    print('-' * len(head))
    for case in cases:
        ku, tu = exact_ultimate(case)
        for noise in (0.0, 0.01):
            errs, times = [], []
            for seed in range(args.seeds if noise else 1):
                t, u, y, eps = relay_run(case, noise, seed, args.spp)
                cycles = relay_cycles(t, u, y, 0.0)[1:5]
                t0 = time.perf_counter()
                res = identify_relay(t, u, y, 0.0, 0.0, eps, cycles=cycles)
                times.append(1e3 * (time.perf_counter() - t0))
                errs.append([res.ku_df / ku - 1, res.tu_df / tu - 1, res.ku_fh / ku - 1,
                             res.tu_fh / tu - 1, res.ku_model / ku - 1, res.tu_model / tu - 1,
                             res.ku / ku - 1, res.tu / tu - 1])
            e = 100 * np.array(errs)
            med, worst = np.median(e, axis=0), np.max(np.abs(e), axis=0)
            cells = ' | '.join(' '.join(f'{m:+6.2f}/{w:5.2f}' for m, w in zip(med[i:i + 2], worst[i:i + 2]))
                               for i in (0, 2, 4, 6))
            kind, *_, dead = PLANTS[case]
            name = f'{kind} L={dead:g}' if kind != 'IPDT' else 'IPDT'
            print(f'{name:>12} {noise * 100:5.0f}% | {cells} | {np.median(times):8.1f}')
    if args.closed_loop:
        closed_loop_table(args.seeds)


if __name__ == '__main__':
    main()
