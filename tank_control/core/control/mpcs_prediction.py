"""Condensed MPCS prediction and cost with dead times ([Michalski2021] §4 and §6, [Michalski2021] §4, §6).

``Ŷ = M_z z + G ΔU`` and ``ŷ_∞ = M∞ z + G∞ ΔU`` with the known vector
``z = [ξ̂(k|k), inputs still in the delay lines, u(k−1), d(k)]`` (deviations) and the future
moves ``ΔU`` (one every ``block`` samples); cost
``J = Σ_p ||W_y (r − ŷ(p))||² + w_∞·||W_y (r − ŷ_∞)||² + Σ_j λ·||Δu(k+t_j)||²``.
``align`` counts a delayed output's horizon from its dead time; ``w_∞`` tells a horizon shorter
than F_Cin's 180 samples what F_Cin is for (docs/mpcs.md, "Horizons and dead times").
Units: cm, °C, cm³/s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tank_control.core.control.mpcs_estimator import AugmentedSystem


@dataclass(frozen=True)
class CostConfig:
    """Horizons and weights of the cost (units: outputs cm and °C, inputs cm³/s)."""

    horizon: int = 100                    # N [samples]
    control_horizon: int = 50             # Nu [samples]
    move_weight: tuple[float, ...] = (0.5,)   # λ, scalar or one per input
    output_weights: tuple[float, ...] = (1.0,)  # W_y diagonal, scalar or one per output
    terminal_weight: float = 0.0          # w_∞ (weight of the steady-state term)
    block: int = 1                        # move blocking: a move every `block` samples
    align: bool = True                    # count each output's horizon from its dead time


def _per_channel(values: tuple[float, ...], n: int, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float).ravel()
    if arr.size == 1:
        arr = np.full(n, arr[0])
    if arr.size != n:
        raise ValueError(f'{name}: expected 1 or {n} values, got {arr.size}')
    return arr


class Prediction:
    """The condensed prediction matrices and the cost's Hessian/linear terms.

    ``z`` layout: ``[ξ̂ (sys.n), delay-line inputs (Σ input_delays), u_prev (n_u), d (n_d)]``,
    each delay line oldest first (``u_m(k−d_m) … u_m(k−1)``). The estimated disturbance ``w`` is
    held constant over the horizon, the measured ``d`` at its current value (feed-forward).
    """

    def __init__(self, sys: AugmentedSystem, cost: CostConfig) -> None:
        m = sys.model
        n, nu, ny, nd = m.n_x, m.n_u, m.n_y, m.n_d
        big_n, nu_h, blk = cost.horizon, cost.control_horizon, cost.block
        if big_n < 1 or nu_h < 1 or blk < 1:
            raise ValueError('mpcs: horizon, control_horizon and block must be >= 1')
        if nu_h > big_n:
            raise ValueError(f'mpcs.control_horizon: {nu_h} exceeds mpcs.horizon {big_n}')
        self.sys, self.cost = sys, cost
        self.n_moves = math.ceil(nu_h / blk)
        self.move_times = np.arange(self.n_moves) * blk
        self.n_dec = self.n_moves * nu
        # --- layout of z
        self.i_xi = 0
        self.i_buf = []
        idx = sys.n
        for dm in m.input_delays:
            self.i_buf.append(idx)
            idx += dm
        self.i_uprev = idx
        self.i_d = idx + nu
        self.n_z = idx + nu + nd
        nv = self.n_z + self.n_dec           # columns: [z, ΔU]
        w_sel = np.zeros((sys.n_w, nv))
        w_sel[:, n + np.arange(sys.n_w)] = np.eye(sys.n_w)
        d_sel = np.zeros((nd, nv))
        d_sel[:, self.i_d:self.i_d + nd] = np.eye(nd)
        const = m.b_d @ d_sel
        if sys.kind == 'input':
            const = const + w_sel
        offsets = [m.output_delays[i] if cost.align else 0 for i in range(ny)]
        steps = [p + offsets[i] - m.output_delays[i]
                 for i in range(ny) for p in range(1, big_n + 1)]
        n_steps = max(max(steps), 0)
        xs = np.zeros((n_steps + 1, n, nv))
        xs[0, :, :n] = np.eye(n)
        drive = np.matmul(m.b_u, self._input_rows(m, n_steps, nv))     # B_u u_eff(k+j)
        for j in range(n_steps):
            xs[j + 1] = m.a @ xs[j] + drive[j] + const
        # --- outputs, ordered p-major: row (p−1)·ny + i
        y_rows = np.zeros((big_n * ny, nv))
        p = np.arange(1, big_n + 1)
        for i in range(ny):
            s = p + offsets[i] - m.output_delays[i]
            rows = np.zeros((big_n, nv))
            ahead = s >= 0
            rows[ahead] = m.c[i] @ xs[s[ahead]]
            known = np.flatnonzero(~ahead)                # still in the register: known past
            rows[known, sys.reg_start[i] - s[known] - 1] = 1.0
            if sys.kind == 'output':
                rows = rows + w_sel[i]
            y_rows[i::ny] = rows
        # --- steady state reached when the last planned inputs are held
        u_last = np.zeros((nu, nv))
        u_last[:, self.i_uprev:self.i_uprev + nu] = np.eye(nu)
        for j in range(self.n_moves):
            u_last[:, self.n_z + j * nu:self.n_z + (j + 1) * nu] += np.eye(nu)
        x_inf = np.linalg.solve(np.eye(n) - m.a, m.b_u @ u_last + const)
        y_inf = m.c @ x_inf
        if sys.kind == 'output':
            y_inf = y_inf + w_sel[:ny]
        self.m_z, self.g = y_rows[:, :self.n_z], y_rows[:, self.n_z:]
        self.m_inf, self.g_inf = y_inf[:, :self.n_z], y_inf[:, self.n_z:]
        # --- cost
        wy2 = _per_channel(cost.output_weights, ny, 'mpcs.output_weights') ** 2
        lam = _per_channel(cost.move_weight, nu, 'mpcs.lambda')
        if np.any(wy2 < 0) or np.any(lam < 0) or cost.terminal_weight < 0:
            raise ValueError('mpcs: weights must be >= 0')
        q = np.tile(wy2, big_n)
        qg = self.g * q[:, None]
        qinf = cost.terminal_weight * wy2
        self.hessian = (self.g.T @ qg + self.g_inf.T @ (self.g_inf * qinf[:, None])
                        + np.diag(np.tile(lam, self.n_moves)))
        # f = F_z z − F_r r   (r: setpoint deviations, constant over the horizon)
        self.f_z = qg.T @ self.m_z + (self.g_inf * qinf[:, None]).T @ self.m_inf
        r_tile = np.tile(np.eye(ny), (big_n, 1))
        self.f_r = qg.T @ r_tile + (self.g_inf * qinf[:, None]).T
        try:
            h_inv = np.linalg.inv(self.hessian)
        except np.linalg.LinAlgError as exc:
            raise ValueError('mpcs: cost Hessian is singular (lambda = 0 with an input '
                             'that has no effect within the horizon?)') from exc
        if not np.all(np.isfinite(h_inv)) or np.linalg.cond(self.hessian) > 1e12:
            raise ValueError('mpcs: cost Hessian is ill-conditioned; increase mpcs.lambda')
        # analytic first move: Δu(k) = −K_z z + K_r r       ([Michalski2021] §4, §6 "analytic")
        first = h_inv[:nu]
        self.k_z = first @ self.f_z
        self.k_r = first @ self.f_r
        # cumulative-sum matrix: u(k+t_j) − u_prev = L ΔU
        self.cum = np.kron(np.tril(np.ones((self.n_moves, self.n_moves))), np.eye(nu))

    def _input_rows(self, m, n_steps: int, nv: int) -> np.ndarray:
        """``u_eff(k+j)`` for ``j < n_steps`` as rows over ``[z, ΔU]``, shape
        ``(n_steps, n_u, nv)``: a value still in input m's delay line (``j < d_m``) is a
        known past input; later ``u_m(k+i) = u_prev_m + Σ_{t_j ≤ i} Δ_{j,m}``, ``i = j − d_m``."""
        nu = m.n_u
        rows = np.zeros((n_steps, nu, nv))
        j = np.arange(n_steps)
        move_cols = self.n_z + nu * np.arange(self.n_moves)
        for mi, dm in enumerate(m.input_delays):
            past = j[j < dm]
            rows[past, mi, self.i_buf[mi] + past] = 1.0
            ahead = j[j >= dm]
            rows[ahead, mi, self.i_uprev + mi] = 1.0
            made = self.move_times[None, :] <= (ahead - dm)[:, None]
            rows[ahead[:, None], mi, (move_cols + mi)[None, :]] = made
        return rows

    def z_vector(self, xi: np.ndarray, buffers: list[np.ndarray], u_prev: np.ndarray,
                 d: np.ndarray) -> np.ndarray:
        """Assemble ``z`` from the estimate, the delay lines, ``u(k−1)`` and ``d(k)``."""
        parts = [xi] + [b for b in buffers if b.size] + [u_prev, d]
        return np.concatenate(parts)
