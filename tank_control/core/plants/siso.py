"""Common machinery of the SISO dead-time plants (IPDT [Viteckova] eq. 1, FOPDT [DeadTimeNotes] eq. 6.14).

Structure ([Viteckova] Fig. 1): the load disturbance ``v`` enters at the plant input,
``y = y0 + G(s)·(u + v)`` with ``G(s) = G0(s)·e^(−L·s)``. The sum ``w = u + v``
is held constant over each step (ZOH), delayed exactly by a ``DelayLine``, and
the delay-free part ``G0`` is advanced in closed form over every constant piece
of the delayed input, so the outputs at the sample instants do not depend on
the step size (exact discretisation, no integration error).

``y0 = output_offset`` is the output the plant holds at rest with ``u + v = 0``;
changing it live shifts the output by the difference.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from math import isfinite
from typing import Any

import numpy as np

from tank_control.core.interfaces import NS_PER_S, StatusValue, seconds, to_ns
from tank_control.core.params import check_config, config_from, param
from tank_control.core.plants.delay_line import DelayLine

MAX_DEAD_TIME_LIMIT = 1e4
"""Largest ``max_dead_time`` [s] a plant may be built with."""
INPUT_LIMIT = 1e12
"""|u + v| beyond this is clipped (counted in ``status['clipped_inputs']``): with the gains'
bounds the delay-free state's changes stay finite."""
STATE_LIMIT = 1e15
"""|state| beyond this is clipped (counted in ``status['clipped_states']``): an integrating or
unstable plant driven for long stays finite (its output saturates there)."""


def dead_time_param(default: float) -> Any:
    """``dead_time``: the transport delay L [s] of the SISO plants."""
    return param(default, 'transport delay L (To in [Viteckova]); changes live, history is kept up to '
                 'max_dead_time', unit='s', min=0.0, max=MAX_DEAD_TIME_LIMIT)


def output_offset_param() -> Any:
    """``output_offset``: y0, the output at rest with u + v = 0."""
    return param(0.0, 'output y0 at rest with u + v = 0; a live change shifts y',
                 unit='output units', min=-1e12, max=1e12)


def max_dead_time_param(default: float = 100.0) -> Any:
    """``max_dead_time``: the input history kept by the delay line (read-only)."""
    return param(default, 'input history kept by the delay line; the largest dead_time allowed',
                 unit='s', min=0.0, max=MAX_DEAD_TIME_LIMIT, read_only=True)


def dead_time_reason(config: Any) -> str | None:
    """``dead_time`` must fit in the stored history (``max_dead_time``)."""
    if config.dead_time > config.max_dead_time:
        return (f'dead_time: {config.dead_time:g} is above max_dead_time; '
                f'allowed [0, {config.max_dead_time:g}]')
    return None


def as_vector(name: str, values: Any, size: int, allow_empty: bool = False) -> np.ndarray:
    """A finite 1-D float vector of ``size`` items (or empty if allowed), else ``ValueError``."""
    vector = np.asarray(values, dtype=np.float64).reshape(-1)
    if vector.size != size and not (allow_empty and vector.size == 0):
        raise ValueError(f'{name}: {vector.size} values given, expected {size}')
    if not np.all(np.isfinite(vector)):
        raise ValueError(f'{name}: non-finite value in {vector.tolist()}')
    return vector


_FLOAT64 = np.dtype(np.float64)


def as_floats(name: str, values: Any, size: int, allow_empty: bool = False) -> list[float]:
    """:func:`as_vector` as a list of Python floats (same checks, same ``ValueError``).

    A 1-D float64 array (what the nodes and the in-process loop pass) or a tuple or list of
    Python floats is checked element by element without building another array.
    """
    if type(values) is np.ndarray and values.dtype is _FLOAT64 and values.ndim == 1:
        items = values.tolist()
    elif type(values) in (tuple, list) and all(type(item) is float for item in values):
        items = list(values)
    else:
        return as_vector(name, values, size, allow_empty).tolist()
    if len(items) == size:
        if isfinite(sum(items)):    # then no item is infinite or NaN (an overflow: see below)
            return items
        for item in items:
            if not isfinite(item):
                break
        else:
            return items
    elif allow_empty and not items:
        return items
    return as_vector(name, values, size, allow_empty).tolist()


def checked_dt(dt: float) -> int:
    """A step length in seconds → integer nanoseconds (finite, >= 0), else ``ValueError``."""
    if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt >= 0.0):
        raise ValueError(f'dt: {dt!r} must be a finite number of seconds >= 0')
    return to_ns(float(dt))


class StepLength:
    """:func:`checked_dt` remembering the last float step length (a plant steps with one
    ``dt`` again and again)."""

    def __init__(self) -> None:
        self._dt = math.nan
        self._dt_ns = 0

    def ns(self, dt: float) -> int:
        """``checked_dt(dt)``: integer nanoseconds, ``ValueError`` for a bad ``dt``."""
        if type(dt) is float and dt == self._dt:
            return self._dt_ns
        dt_ns = checked_dt(dt)
        self._dt, self._dt_ns = float(dt), dt_ns
        return dt_ns


class DeadTimePlant:
    """Base of IPDT/FOPDT: channels ``y``/``u``/``v``, delay line, live configuration.

    Subclasses implement ``_advance(x, w, duration)``: the delay-free state after
    ``duration`` seconds of constant delayed input ``w``.
    """

    output_names: tuple[str, ...] = ('y',)
    input_names: tuple[str, ...] = ('u',)
    disturbance_names: tuple[str, ...] = ('v',)
    _x: Any       # the delay-free state: a float (IPDT, FOPDT), a tuple or an array (its kind's)

    def __init__(self, config: Any) -> None:
        self._config = check_config(config)
        self._line = DelayLine(self._config.max_dead_time, initial=0.0)
        self._dt = StepLength()
        self.reset()

    @property
    def config(self) -> Any:
        """The current configuration (a copy; change it with ``configure``)."""
        return self._config

    def configure(self, **changes: Any) -> None:
        """Change parameters live (all-or-nothing); they act from the next ``step``.

        Raises ``ValueError`` with a one-line reason naming the parameter and the
        allowed range; ``max_dead_time`` is read-only (fixed at construction).
        """
        self._config = config_from(type(self._config), changes, self._config, live=True)

    def reset(self) -> None:
        """Back to rest at t = 0: delay line empty (input history 0), y = output_offset."""
        self._line.reset(0.0)
        self._x = 0.0
        self._t_ns = 0
        self._steps = 0
        self._clipped_inputs = 0
        self._clipped_states = 0

    @property
    def time(self) -> float:
        """Plant time [s] (sum of the step lengths since ``reset``)."""
        return seconds(self._t_ns)

    def outputs(self) -> np.ndarray:
        """``[y]`` at the current instant (noise-free)."""
        return np.array([self._config.output_offset + self._x])

    def nominal_inputs(self) -> np.ndarray:
        """Inputs at rest: ``[u] = [0]``."""
        return np.zeros(1)

    def nominal_disturbances(self) -> np.ndarray:
        """Disturbances at rest: ``[v] = [0]`` (also used when ``d`` is empty)."""
        return np.zeros(1)

    def step(self, u: Any, d: Any, dt: float) -> None:
        """Advance ``dt`` seconds with ``u`` and ``v`` held (ZOH); ``d`` may be empty (v = 0).

        Raises ``ValueError`` (state untouched) on a wrong size or non-finite value.
        """
        u_vec = as_floats('u', u, 1)
        d_vec = as_floats('d', d, 1, allow_empty=True)
        dt_ns = self._dt.ns(dt)
        w = u_vec[0] + (d_vec[0] if d_vec else 0.0)   # [Viteckova] Fig. 1: G·(u + v)
        if not -INPUT_LIMIT <= w <= INPUT_LIMIT:       # finite inputs keep finite states
            w = min(max(w, -INPUT_LIMIT), INPUT_LIMIT)
            self._clipped_inputs += 1
        t_ns = self._t_ns
        line = self._line
        line.push(t_ns, w)
        x = self._x
        advance = self._advance
        for duration, w_delayed in line.segments(t_ns, dt_ns / NS_PER_S, self._config.dead_time):
            if duration > 0.0:
                x = advance(x, w_delayed, duration)
        if type(x) is not float or not -STATE_LIMIT <= x <= STATE_LIMIT:
            x = self._bounded(x)                         # (else it returns x)
        self._x = x
        self._t_ns = t_ns + dt_ns
        self._steps += 1

    def _advance(self, x: Any, w: float, duration: float) -> Any:
        """The state (the type ``_x`` has) after ``duration`` [s] of input ``w``."""
        raise NotImplementedError

    def _bounded(self, x: Any) -> Any:
        """``x`` (a float, a tuple of floats or an array) with every item within
        ±STATE_LIMIT; a clipped step is counted."""
        if type(x) is float:
            if -STATE_LIMIT <= x <= STATE_LIMIT:
                return x
            self._clipped_states += 1
            return min(max(x, -STATE_LIMIT), STATE_LIMIT) if x == x else 0.0
        items = np.asarray(x, dtype=float)
        if np.all(np.abs(items) <= STATE_LIMIT):
            return x
        self._clipped_states += 1
        items = np.clip(np.nan_to_num(items, nan=0.0), -STATE_LIMIT, STATE_LIMIT)
        return tuple(items.tolist()) if isinstance(x, tuple) else items

    @property
    def status(self) -> Mapping[str, StatusValue]:
        """``time`` [s], ``steps``, ``dead_time`` [s] in force, ``history_breakpoints``,
        ``clipped_inputs``/``clipped_states``: steps whose input or state was clipped."""
        return {'time': self.time, 'steps': self._steps,
                'dead_time': self._config.dead_time,
                'history_breakpoints': len(self._line),
                'clipped_inputs': self._clipped_inputs, 'clipped_states': self._clipped_states}
