"""MPCS estimator design: the filter Riccati equation by doubling against scipy's solver.

Solves the steady-state Kalman filter Riccati equation of the augmented MPCS tank model (default
``MpcsConfig``: 124 states) with ``mpcs_estimator.filter_riccati`` (structure-preserving
doubling) and with ``scipy.linalg.solve_discrete_are`` (generalized Schur), checks that both
give the same P, and prints the median wall time of each [ms] and their ratio.

    .venv/bin/python bench/bench_riccati.py [--runs 7]
"""
from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
from scipy.linalg import solve_discrete_are

from tank_control.core.control.mpcs import MpcsConfig
from tank_control.core.control.mpcs_estimator import (EstimatorConfig, KalmanEstimator,
                                                      filter_riccati)
from tank_control.core.control.mpcs_model import tank_model


def median_ms(solve: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        solve()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=7)
    args = parser.parse_args()
    cfg = MpcsConfig()
    est = KalmanEstimator(tank_model(cfg.operating_point(), cfg.sample_time),
                          EstimatorConfig(cfg.disturbance_model, cfg.disturbance_noise,
                                          cfg.state_noise))
    s, ec = est.sys, est.config
    q = np.zeros(s.n)
    q[:s.model.n_x] = ec.state_noise
    q[s.model.n_x:s.model.n_x + s.n_w] = ec.disturbance_noise
    q = np.diag(q)
    r = ec.measurement_noise * np.eye(s.model.n_y)
    p_doubling = filter_riccati(s.a, s.c, q, r)
    p_schur = solve_discrete_are(s.a.T, s.c.T, q, r)
    diff = np.abs(p_doubling - p_schur).max() / np.abs(p_schur).max()
    doubling = median_ms(lambda: filter_riccati(s.a, s.c, q, r), args.runs)
    schur = median_ms(lambda: solve_discrete_are(s.a.T, s.c.T, q, r), args.runs)
    print(f'{s.n} states; max|P_doubling - P_schur| / max|P| = {diff:.1e}')
    print(f'median of {args.runs}: doubling {doubling:.1f} ms, solve_discrete_are {schur:.1f} ms, '
          f'ratio {schur / doubling:.1f}')


if __name__ == '__main__':
    main()
