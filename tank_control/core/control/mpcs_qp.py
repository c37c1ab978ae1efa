"""The constrained MPCS step as a dense QP ([Michalski2021] §6, [Michalski2021] §4, §6 "numeric").

    minimise   ½ xᵀ H x + fᵀ x
    subject to lb ≤ x ≤ ub                   (|Δu| ≤ du_max, slack ≥ 0)
               lo ≤ A x ≤ hi                 (u_min ≤ u ≤ u_max, soft output bounds)

Solved with DAQP (dual active set; the choice against quadprog, proxsuite and OSQP:
bench/RESULTS.md, "MPCS"). One DAQP workspace per design is reused every sample: only ``f`` and
the bounds change, and the previous sample's active set is the starting point (warm start).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

try:  # the QP library is optional at import time: the analytic solver needs none
    import daqp
except ImportError:  # pragma: no cover - exercised only without the dependency
    daqp = None

BIG = 1e20     # stands for ±inf in the solver's bounds


@dataclass
class QpResult:
    """Outcome of one solve: ``x`` is ``None`` when the solve failed."""

    x: np.ndarray | None
    exitflag: int
    iterations: int
    active: int            # number of active inequality constraints/bounds
    seconds: float


class DenseQp:
    """A fixed-structure QP solved repeatedly with new ``f`` and bounds."""

    def __init__(self, hessian: np.ndarray, a: np.ndarray, iter_limit: int = 1000) -> None:
        if daqp is None:
            raise ValueError("mpcs.solver: 'qp' needs the daqp package (pip install daqp)")
        self.h = np.ascontiguousarray(hessian, dtype=float)
        self.a = np.ascontiguousarray(a, dtype=float)
        self.n = self.h.shape[0]
        self.iter_limit = iter_limit
        self._model: Any = None                 # the solver's workspace, set up at the first solve

    def __deepcopy__(self, memo: dict) -> DenseQp:
        """A copy with its own workspace, made at its first solve (DAQP's workspace cannot be
        copied): the same QP; only the warm start of the first solve is lost."""
        copy = DenseQp.__new__(DenseQp)
        copy.h, copy.a, copy.n, copy.iter_limit = self.h.copy(), self.a.copy(), self.n, \
            self.iter_limit
        copy._model = None
        memo[id(self)] = copy
        return copy

    def solve(self, f: np.ndarray, lb: np.ndarray, ub: np.ndarray,
              lo: np.ndarray, hi: np.ndarray) -> QpResult:
        """Solve; bounds may contain ±inf. Never raises for numerical failures."""
        start = time.perf_counter()
        upper = np.minimum(np.maximum(np.concatenate([ub, hi]), -BIG), BIG)   # np.clip
        lower = np.minimum(np.maximum(np.concatenate([lb, lo]), -BIG), BIG)
        f = np.ascontiguousarray(f, dtype=float)
        try:
            if self._model is None:
                if daqp is None:
                    raise ImportError('daqp is not installed')   # the fallback below
                self._model = daqp.Model()
                self._model.settings = {'iter_limit': self.iter_limit}
                flag, _ = self._model.setup(self.h, f, self.a, upper, lower)
                if flag < 0:
                    self._model = None
                    return QpResult(None, int(flag), 0, 0, time.perf_counter() - start)
            else:
                self._model.update(f=f, bupper=upper, blower=lower)
            x, _, flag, info = self._model.solve()
        except Exception:      # noqa: BLE001 - any solver error becomes a fallback
            self._model = None
            return QpResult(None, -99, 0, 0, time.perf_counter() - start)
        x = np.asarray(x, dtype=float)
        ok = flag >= 1 and bool(np.isfinite(x).all())
        lam = np.asarray(info.get('lam', ()), dtype=float)
        active = int(np.count_nonzero(np.abs(lam) > 1e-9)) if lam.size else 0
        if not ok:
            self._model = None          # start the next solve from a clean workspace
        return QpResult(x if ok else None, int(flag), int(info.get('iterations', 0)), active,
                        time.perf_counter() - start)
