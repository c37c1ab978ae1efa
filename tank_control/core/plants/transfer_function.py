"""Transfer-function plant with dead time, ``G(s) = B(s)/A(s) · e^(−L·s)`` ([Checks] §5).

``num`` and ``den`` are the coefficients of ``B`` and ``A`` in descending powers of ``s``;
``G`` must be strictly proper (degree of ``B`` below that of ``A``). Load ``v`` at the input,
``y = y0 + G(s)·(u + v)`` ([Viteckova] Fig. 1), as the other SISO plants. Unstable and integrating
denominators are allowed: [Ikonen]'s process ``4/((s + 1)(s + 2))`` is ``num [4]``,
``den [1, 3, 2]``; a first-order unstable process with dead time ``K/(T·s − 1)·e^(−L·s)`` is
``num [K]``, ``den [T, −1]``.

State: the controllable canonical form of ``B/A`` (``den`` normalised to a monic ``A``).
Exact discretisation: over a piece of constant delayed input ``w`` lasting ``τ`` seconds,
``x ← Φ(τ)·x + Γ(τ)·w`` with ``[[Φ, Γ], [0, 1]] = exp([[A, b], [0, 0]]·τ)`` (the zero-order
hold), so the outputs at the sample instants do not depend on the step size. ``Φ, Γ`` are
kept for the few piece lengths a run uses. Times in s; ``y`` in output units.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from tank_control.core.scipy_lazy import expm

from tank_control.core.interfaces import StatusValue
from tank_control.core.params import param
from tank_control.core.plants.siso import (DeadTimePlant, dead_time_param, dead_time_reason,
                                           max_dead_time_param, output_offset_param)

MAX_ORDER = 10
"""Highest degree of the denominator accepted."""

_BIG = 1e12
"""Largest magnitude of a coefficient accepted."""

_KEPT = 8
"""Piece lengths whose ``Φ, Γ`` are kept (a run uses the tick and the dead time's remainders)."""


@dataclass(frozen=True)
class TransferFunctionConfig:
    """Parameters of ``TransferFunction`` (defaults: [Ikonen]'s process 4/((s + 1)(s + 2)), L = 0)."""

    num: tuple[float, ...] = param((4.0,), 'numerator B(s): coefficients in descending powers '
                                   'of s', unit='output units/input unit', min=-_BIG, max=_BIG,
                                   source='[Ikonen], reconstructed in [Checks] §5')
    den: tuple[float, ...] = param((1.0, 3.0, 2.0), 'denominator A(s): coefficients in '
                                   'descending powers of s, degree above that of num (at most '
                                   f'{MAX_ORDER}); a live change keeps its degree',
                                   min=-_BIG, max=_BIG,
                                   source='[Ikonen], reconstructed in [Checks] §5')
    dead_time: float = dead_time_param(0.0)
    output_offset: float = output_offset_param()
    max_dead_time: float = max_dead_time_param()

    def reason(self) -> str | None:
        den = _trimmed(self.den)
        if not den:
            return f'den: {list(self.den)} has no non-zero coefficient'
        if len(den) - 1 > MAX_ORDER:
            return f'den: degree {len(den) - 1} is above {MAX_ORDER}'
        num = _trimmed(self.num)
        if len(num) >= len(den):
            return (f'num: degree {max(len(num) - 1, 0)} must be below the degree '
                    f'{len(den) - 1} of den (a strictly proper B(s)/A(s))')
        lead = den[0]
        if any(not abs(c / lead) <= _BIG ** 2 for c in (*den[1:], *num)):
            return (f'den: the leading coefficient {lead:g} is too small for the others (num, '
                    f'den divided by it exceed {_BIG ** 2:g}); allowed: ratios to the leading '
                    'coefficient within that')
        return dead_time_reason(self)


def _trimmed(coefficients: tuple[float, ...]) -> list[float]:
    """The coefficients without leading zeros (``[]`` for the zero polynomial)."""
    values = [float(c) for c in coefficients]
    while values and values[0] == 0.0:
        values.pop(0)
    return values


def canonical_form(config: TransferFunctionConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, b, c)`` of the controllable canonical form of ``num/den``: ``ẋ = A·x + b·w``,
    ``y − y0 = c·x``, with ``x[0]`` the highest derivative of the internal variable."""
    den = np.array(_trimmed(config.den))
    den = den / den[0]                        # monic A(s)
    n = len(den) - 1
    num = np.zeros(n)
    coefficients = np.array(_trimmed(config.num)) / _trimmed(config.den)[0]
    if coefficients.size:
        num[n - coefficients.size:] = coefficients
    a = np.zeros((n, n))
    a[0, :] = -den[1:]
    a[1:, :-1] = np.eye(n - 1)
    b = np.zeros(n)
    b[0] = 1.0
    return a, b, num


class TransferFunction(DeadTimePlant):
    """``B(s)/A(s) · e^(−L·s)`` with input load disturbance; channels ``y``/``u``/``v``."""

    def __init__(self, config: TransferFunctionConfig | None = None) -> None:
        super().__init__(config if config is not None else TransferFunctionConfig())

    def configure(self, **changes: Any) -> None:
        """Change parameters live (all-or-nothing; module docstring). The state is kept, so a
        change of ``den``'s degree, which would change its size, is refused."""
        old = self._config
        super().configure(**changes)
        if len(_trimmed(self._config.den)) != len(_trimmed(old.den)):
            new, self._config = self._config, old
            raise ValueError(f'den: degree {len(_trimmed(new.den)) - 1} differs from the running '
                             f'{len(_trimmed(old.den)) - 1}; a change of order needs a restart')
        self._model()

    def reset(self) -> None:
        """Back to rest at t = 0: input history 0, state 0, y = output_offset."""
        super().reset()
        self._model()
        self._x = np.zeros(self._a.shape[0])

    def _model(self) -> None:
        self._a, self._b, self._c = canonical_form(self._config)
        self._pieces: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def outputs(self) -> np.ndarray:
        """``[y]`` at the current instant (noise-free)."""
        return np.array([self._config.output_offset + float(self._c @ self._x)])

    def _advance(self, x: np.ndarray, w: float, duration: float) -> np.ndarray:
        piece = self._pieces.get(duration)
        if piece is None:
            n = self._a.shape[0]
            block = np.zeros((n + 1, n + 1))
            block[:n, :n] = self._a
            block[:n, n] = self._b
            e = expm(block * duration)
            piece = (e[:n, :n], e[:n, n])
            if len(self._pieces) >= _KEPT:
                self._pieces.pop(next(iter(self._pieces)))
            self._pieces[duration] = piece
        return piece[0] @ x + piece[1] * w

    @property
    def static_gain(self) -> float:
        """``B(0)/A(0)``: ``inf`` for an integrating ``A`` (``A(0) = 0``)."""
        num, den = _trimmed(self._config.num), _trimmed(self._config.den)
        b0 = num[-1] if num else 0.0
        return b0 / den[-1] if den[-1] != 0.0 else math.copysign(math.inf, b0 or 1.0)

    @property
    def status(self) -> Mapping[str, StatusValue]:
        """As the other SISO plants, and ``order`` (the degree of ``den``)."""
        return {**super().status, 'order': int(self._a.shape[0])}
