"""A minimal nonlinear mixing tank (SPEC §1.3) for MPCS tests, independent of the MPCS code.

RK4 with 10 sub-steps per sample; F_Cin delayed by tau_c and T by tau through
sample-indexed delay lines (valid when the delays are multiples of the sample).
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np


class SimTank:
    output_names = ('h', 'T_out')
    input_names = ('F_H', 'F_Cin')
    disturbance_names = ('F_D', 'T_D')

    def __init__(self, h0=81.0, T0=2115.0 / 63.0, F_Cin0=37.0, ts=1.0, tau=120.0, tau_c=180.0,
                 C=0.7, alpha=7.0, T_H=62.0, T_C=23.0):
        self.C, self.alpha, self.T_H, self.T_C, self.ts = C, alpha, T_H, T_C, ts
        self.V, self.T = C * h0 ** 2, T0
        self.fc_line = deque([F_Cin0] * int(round(tau_c / ts)))
        self.t_line = deque([T0] * int(round(tau / ts)))

    def outputs(self) -> np.ndarray:
        t_out = self.t_line[0] if self.t_line else self.T
        return np.array([math.sqrt(self.V / self.C), t_out])

    def _f(self, v, t, fh, fc, fd, td):
        fin = fh + fc + fd
        dv = fin - self.alpha * math.sqrt(math.sqrt(max(v, 0.0) / self.C))   # F = alpha·√h
        dt = (fh * self.T_H + fc * self.T_C + fd * td - fin * t) / v
        return dv, dt

    def step(self, u, d, dt):
        fh, fcin = float(u[0]), float(u[1])
        fd, td = float(d[0]), float(d[1])
        if self.fc_line:
            self.fc_line.append(fcin)
            fc = self.fc_line.popleft()
        else:
            fc = fcin
        if self.t_line:
            self.t_line.append(self.T)
            self.t_line.popleft()
        n = 10
        h = dt / n
        v, t = self.V, self.T
        for _ in range(n):
            k1 = self._f(v, t, fh, fc, fd, td)
            k2 = self._f(v + h / 2 * k1[0], t + h / 2 * k1[1], fh, fc, fd, td)
            k3 = self._f(v + h / 2 * k2[0], t + h / 2 * k2[1], fh, fc, fd, td)
            k4 = self._f(v + h * k3[0], t + h * k3[1], fh, fc, fd, td)
            v += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            t += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        self.V, self.T = v, t
