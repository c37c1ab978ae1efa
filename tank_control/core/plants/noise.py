"""Gaussian measurement noise per output channel, reproducible by seed.

Draw order (the contract shared by ``core/loop.py`` and ``plant_node``):

* one ``MeasurementNoise`` per plant, built from ``seed``; ``reset()`` restarts
  the stream (``numpy.random.default_rng(seed)``, PCG64);
* exactly one call of ``sample()`` (or ``apply(y)``) per sample instant k, in
  tick order, and none otherwise — a re-sent measurement of tick k must reuse
  the value drawn for tick k, not draw again;
* every call draws ``standard_normal(n)`` for all ``n`` output channels in the
  order of ``output_names`` (fetched from the generator ``_BATCH`` instants at a time: the
  same numbers), whatever the standard deviations are, so a zero
  ``std`` on one channel (exactly no noise there) or a live change of ``std``
  never shifts the random numbers of the other channels or later ticks.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tank_control.core.params import param


@dataclass(frozen=True)
class NoiseConfig:
    """The plant node's measurement noise (parameters ``noise_std``, ``seed``)."""

    noise_std: tuple[float, ...] = param((0.0,), 'standard deviation of the Gaussian '
                                         'measurement noise per output channel; one value '
                                         'applies to every channel', unit='output units',
                                         min=0.0, max=1e6)
    seed: int = param(0, 'seed of the measurement-noise generator (numpy PCG64)', min=0,
                      max=2 ** 63 - 1, read_only=True)


def _std_vector(std: float | Sequence[float], n: int) -> np.ndarray:
    values = np.atleast_1d(np.asarray(std, dtype=np.float64))
    if values.size == 1:
        values = np.full(n, values[0])
    if values.size != n:
        raise ValueError(f'noise_std: {values.size} values for {n} output channels; '
                         f'give 1 or {n}')
    if not np.all(np.isfinite(values)) or np.any(values < 0.0):
        raise ValueError(f'noise_std: {values.tolist()} must be finite and >= 0')
    return values


_BATCH = 256
"""Sample instants of standard normal draws fetched from the generator at once."""


class MeasurementNoise:
    """Additive white Gaussian noise ``y_measured = y + std · z``, ``z ~ N(0, I)``."""

    def __init__(self, n_outputs: int, std: float | Sequence[float] = 0.0, seed: int = 0) -> None:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f'seed: {seed!r} must be an integer >= 0')
        self.n_outputs = int(n_outputs)
        self.seed = int(seed)
        self._set_std(_std_vector(std, self.n_outputs))
        self.reset()

    @property
    def std(self) -> np.ndarray:
        """Standard deviation per channel (a copy)."""
        return self._std.copy()

    def _set_std(self, values: np.ndarray) -> None:
        self._std = values.copy()
        self._std_floats: list[float] = values.tolist()
        self._all_noisy = bool(np.all(values > 0.0))     # std·z on every channel
        self._silent = not np.any(values > 0.0)          # exactly 0 on every channel

    def set_std(self, std: float | Sequence[float]) -> None:
        """Change the standard deviations live; the random stream is unaffected."""
        self._set_std(_std_vector(std, self.n_outputs))

    def reset(self) -> None:
        """Restart the random stream from ``seed``."""
        self._rng = np.random.default_rng(self.seed)
        self._z: list[float] = []      # draws fetched ahead (_BATCH instants), from _next on
        self._next = 0

    def _draws(self) -> list[float]:
        """The next ``standard_normal(n_outputs)`` of the stream. Fetched ``_BATCH`` instants
        at a time: ``standard_normal(n·k)`` is the same numbers as k calls of
        ``standard_normal(n)`` (one generator, drawn in order), for a fraction of the calls."""
        n = self.n_outputs
        i = self._next
        if i + n > len(self._z):
            self._z = self._rng.standard_normal(n * _BATCH).tolist()
            i = 0
        self._next = i + n
        return self._z[i:i + n]

    def sample(self) -> np.ndarray:
        """The noise of the next sample instant (always ``n_outputs`` draws)."""
        return np.array(self.sample_floats(), dtype=np.float64)

    def sample_floats(self) -> list[float]:
        """:meth:`sample` as Python floats: ``std·z`` per channel, exactly 0 where std is 0."""
        z = self._draws()
        if self._all_noisy:
            return [s * v for s, v in zip(self._std_floats, z)]
        if self._silent:
            return [0.0] * self.n_outputs
        return [s * v if s > 0.0 else 0.0 for s, v in zip(self._std_floats, z)]

    def apply(self, y: np.ndarray) -> np.ndarray:
        """``y`` plus the noise of the next sample instant (a new array)."""
        return np.asarray(y, dtype=np.float64) + self.sample()
