"""Frequency points from the relay transient ([Precup2013] eqs. 3.3.1–3.3.10): what they need.

Part A — ``transient_response`` on a relay record from rest (ideal relay ±1, hysteresis 4σ,
exact ZOH plant sampled at 0.1 s) of [DeadTimeNotes]'s FOPDT 0.05/(10s + 1)·e^(−3s) (ωc = 2π/10.82 s) and
of the IPDT 0.05/s·e^(−5s) (ωc = 2π/20 s): record length, α, cut (horizon) and the Gaussian
lag window (Tu/20) varied; the error is the worst over 0.25, 0.5, 1, 1.5, 2·ωc of |Ĝ/G − 1| [%]
(and of |arg Ĝ − arg G| [°]); with noise σ = 1 % of the relay output amplitude, the median
and the worst of that over ``--seeds`` seeds.

Part B — the whole RelayAutotuner with ``autotune.transient_points`` [0.25, 0.5, 1, 1.5, 2]
(its own α, cut, window and record length from the identified model), started from rest, on
[DeadTimeNotes]'s FOPDT, the IPDT and plants the tests do not use: FOPDT 2/(5s + 1)·e^(−s) and
2/(5s + 1)·e^(−5s), SOPDT e^(−2s)/((10s + 1)(4s + 1)) (with the automatic cut, which takes
the IPDT that ``autotune.model auto`` identifies there, and with autotune.transient_horizon 80 s).
Per point: worst magnitude error [%] and phase error [°] over the seeds; the mean record length.

Usage: .venv/bin/python bench/bench_transient.py [--seeds 10] [--part A|B|AB] [--settle 5]
"""
from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.linalg import expm

from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import AutotuneConfig, RelayAutotuner
from tank_control.core.tuning.identification import transient_response

TE = 0.1
RATIOS = np.array([0.25, 0.5, 1.0, 1.5, 2.0])

# name: (A, B, C, dead time [s], exact G(jω), Tu [s] (for part A), PI before the test)
PLANTS = {
    '[DeadTimeNotes] FOPDT 0.05, 10 s, 3 s': ([[-0.1]], [0.005], [1.0], 3.0,
                                  lambda w: 0.05 * np.exp(-3j * w) / (10j * w + 1), 10.82,
                                  dict(kp=20.0, ti=12.0), 200.0),
    'IPDT 0.05/s, 5 s': ([[0.0]], [0.05], [1.0], 5.0,
                         lambda w: 0.05 * np.exp(-5j * w) / (1j * w), 20.0,
                         dict(kp=1.0, ti=40.0), 1.0),
    'FOPDT 2, 5 s, 1 s': ([[-0.2]], [0.4], [1.0], 1.0,
                          lambda w: 2 * np.exp(-1j * w) / (5j * w + 1), None,
                          dict(kp=1.0, ti=6.0), 1.0),
    'FOPDT 2, 5 s, 5 s': ([[-0.2]], [0.4], [1.0], 5.0,
                          lambda w: 2 * np.exp(-5j * w) / (5j * w + 1), None,
                          dict(kp=0.2, ti=10.0), 1.0),
    'SOPDT 1, 10 s, 4 s, 2 s': ([[-0.1, 0.0], [0.25, -0.25]], [0.1, 0.0], [0.0, 1.0], 2.0,
                                lambda w: np.exp(-2j * w) / ((10j * w + 1) * (4j * w + 1)),
                                None, dict(kp=0.3, ti=14.0), 1.0),
}


class Plant:
    """Exact ZOH sampling of ``(A, B, C)`` with a dead time of whole samples, at rest at 0."""

    def __init__(self, a, b, c, dead: float) -> None:
        a, b = np.array(a, float), np.array(b, float)
        n = a.shape[0]
        m = np.zeros((n + 1, n + 1))
        m[:n, :n], m[:n, n] = a * TE, b * TE
        e = expm(m)
        self.phi, self.gam, self.c = e[:n, :n], e[:n, n], np.array(c, float)
        self.x = np.zeros(n)
        self.queue = [0.0] * int(round(dead / TE))

    def output(self) -> float:
        return float(self.c @ self.x)

    def step(self, u: float) -> None:
        self.queue.append(u)
        self.x = self.phi @ self.x + self.gam * self.queue.pop(0)


def relay_record(name: str, seconds: float, sigma: float, seed: int):
    a, b, c, dead, *_ = PLANTS[name]
    plant, rng, high = Plant(a, b, c, dead), np.random.default_rng(seed), True
    n = int(round(seconds / TE))
    u, y = np.zeros(n), np.zeros(n)
    for k in range(n):
        y[k] = plant.output() + sigma * rng.standard_normal()
        high = True if -y[k] > 4 * sigma else False if -y[k] < -4 * sigma else high
        u[k] = 1.0 if high else -1.0
        plant.step(u[k])
    return np.arange(n) * TE, u, y


def amplitude(name: str) -> float:
    _, _, y = relay_record(name, 200.0, 0.0, 0)
    return 0.5 * float(np.ptp(y[len(y) // 2:]))


def errors(g: np.ndarray, exact: np.ndarray) -> tuple[float, float]:
    return (100 * float(np.abs(g / exact - 1).max()),
            float(np.degrees(np.abs(np.angle(g / exact))).max()))


def part_a(seeds: int) -> None:
    print('Part A: transient_response on a relay record from rest; worst of 0.25…2·ωc, '
          'complex error |Ĝ/G − 1| [%] / phase [°]')
    print('| plant | record [s] | α [1/s] | cut [s] | window | noise-free | 1 % noise: median | '
          '1 % noise: worst |')
    print('|---|---|---|---|---|---|---|---|')
    rows = {
        '[DeadTimeNotes] FOPDT 0.05, 10 s, 3 s': [
            (46, 0.1, 32, False), (46, 0.1, 32, True), (100, 0.1, 70, False),
            (91, 4 / 73, 73, True), (110, 4 / 73, 73, True), (146, 4 / 73, 73, True),
            (219, 4 / 73, 73, True), (146, 4 / 73, 73, False), (146, 4 / 73, 40, True),
            (146, 4 / 73, 50, True), (146, 2 / 73, 73, True), (146, 8 / 73, 73, True),
            (146, 15 / 73, 73, True)],
        'IPDT 0.05/s, 5 s': [
            (86, 0.4, 10, True), (86, 0.4, 10, False), (86, 0.1, 40, True),
            (86, 0.4, 7, True)],
    }
    for name, cases in rows.items():
        _, _, _, _, exact_g, tu, _, _ = PLANTS[name]
        w = 2 * math.pi / tu * RATIOS
        exact = exact_g(w)
        amp = amplitude(name)
        integrating = name.startswith('IPDT')
        for seconds, alpha, cut, window in cases:
            def estimate(sigma: float, seed: int) -> tuple[float, float]:
                t, u, y = relay_record(name, seconds, sigma, seed)
                g = transient_response(t, u, y, 0.0, 0.0, w, alpha, cut,
                                       smoothing=tu / 20 if window else 0.0,
                                       integrating=integrating)
                return errors(g, exact)
            clean = estimate(0.0, 0)
            noisy = np.array([estimate(0.01 * amp, s) for s in range(1, seeds + 1)])
            med, worst = np.median(noisy, axis=0), noisy.max(axis=0)
            print(f'| {name} | {seconds} | {alpha:.3g} | {cut} | {"Tu/20" if window else "none"} '
                  f'| {clean[0]:.2f} % / {clean[1]:.2f}° | {med[0]:.1f} % / {med[1]:.1f}° '
                  f'| {worst[0]:.1f} % / {worst[1]:.1f}° |', flush=True)


SETTLE = {'time': 5.0}
"""autotune.settle_time of part B [s] (``--settle``): the window u0 and y0 are averaged over."""


def tuner_run(name: str, noise: float, seed: int, **settings):
    a, b, c, dead, exact_g, _, pid, d = PLANTS[name]
    amp = amplitude_scaled(name, d)
    tuner = RelayAutotuner(PidConfig(sample_time=TE, **pid), AutotuneConfig(
        relay_amplitude=d, settle_time=SETTLE['time'], settle_band=0.05 * amp, timeout=2000.0,
        transient_points=tuple(RATIOS), **settings))
    tuner.reset(np.array([0.0]), np.array([0.0]))
    tuner.start()
    plant, rng = Plant(a, b, c, dead), np.random.default_rng(seed)
    for k in range(30000):
        y = plant.output() + noise * amp * rng.standard_normal()
        plant.step(float(tuner.step(k * TE, np.array([y]), np.array([0.0]), np.zeros(0))[0]))
        if tuner.state not in ('settling', 'relay', 'measuring'):
            break
    res = tuner.results()
    if res['autotune.state'] not in ('tuned', 'running'):
        raise RuntimeError(f'{name}: {res["autotune.state"]}: {res["autotune.reason"]}')
    w = np.array(res['autotune.transient_omega'])
    if w[0] == 0.0:
        return None                                       # skipped: autotune.warning says why
    exact = exact_g(w)
    gain_err = 100 * (np.array(res['autotune.transient_gain']) / np.abs(exact) - 1)
    phase = np.radians(res['autotune.transient_phase'])
    phase_err = np.degrees(np.angle(np.exp(1j * (phase - np.angle(exact)))))
    return gain_err, phase_err, res['autotune.transient_record'], res['autotune.transient_check']


def amplitude_scaled(name: str, d: float) -> float:
    return d * amplitude(name)


def part_b(seeds: int) -> None:
    print('\nPart B: RelayAutotuner with autotune.transient_points [0.25, 0.5, 1, 1.5, 2], from '
          f"rest, settle_time {SETTLE['time']:g} s; worst magnitude error [%] / phase error [°] "
          'per point over the seeds')
    print('| plant | settings | noise | record [s] | 0.25·ωc | 0.5·ωc | ωc | 1.5·ωc '
          '| 2·ωc | transient_check (worst) |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    cases = [(name, {}) for name in PLANTS] + [
        ('SOPDT 1, 10 s, 4 s, 2 s', {'transient_horizon': 80.0})]
    for name, settings in cases:
        for noise, runs in ((0.0, 1), (0.01, seeds)):
            every = [tuner_run(name, noise, s, **settings) for s in range(1, runs + 1)]
            out = [o for o in every if o is not None]
            g = np.abs(np.array([o[0] for o in out])).max(axis=0)
            p = np.abs(np.array([o[1] for o in out])).max(axis=0)
            rec = np.mean([o[2] for o in out])
            check = max(o[3] for o in out)
            cells = ' | '.join(f'{gi:.2f} % / {pi:.2f}°' for gi, pi in zip(g, p))
            given = ', '.join(f'{k} {v}' for k, v in settings.items()) or 'auto'
            skipped = (f' ({len(every) - len(out)} of {len(every)} skipped)'
                       if len(out) < len(every) else '')
            print(f'| {name} | {given} | {100 * noise:g} %{skipped} | {rec:.0f} | {cells} '
                  f'| {check:.2f} % |', flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seeds', type=int, default=10)
    ap.add_argument('--part', default='AB')
    ap.add_argument('--settle', type=float, default=5.0, help='autotune.settle_time of part B [s]')
    args = ap.parse_args()
    SETTLE['time'] = args.settle
    if 'A' in args.part:
        part_a(args.seeds)
    if 'B' in args.part:
        part_b(args.seeds)


if __name__ == '__main__':
    main()
