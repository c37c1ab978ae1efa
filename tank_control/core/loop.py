"""The discrete-time closed loop run in-process: the reference every ROS run must match.

The arithmetic of the nodes' lockstep protocol (docs/nodes.md), without ROS. With
``ts_ns = to_ns(sample_time)`` of the plant, for tick ``k = 0 … duration_ns // ts_ns``:

1. ``t_k = k·ts_ns`` (integer ns); ``r``, ``d`` from the reference at ``t_k`` (disturbance
   channels it does not schedule keep the plant's nominal values);
2. ``y = plant.outputs() + noise()`` — one noise draw per tick, as plant_node draws;
3. at the controller's sample instants (``t_k % controller_ts_ns == 0``)
   ``u = controller.step(t, y, r, d)``, else the last ``u`` is held; the first sample with
   a finite measurement first warm-starts it (:func:`warm_start`), as controller_node does;
4. record ``t, y.*, r.*, u.*, d.*``; ``plant.step(u, d, sample_time)`` — ZOH over
   ``[t_k, t_k+1)``.

With ``guards`` (:class:`Guards`, what the nodes refuse on their inputs) a value outside its
channel's plausible range (``core/ranges.py``) or non-finite is refused as controller_node and
plant_node refuse it: a setpoint or disturbance keeps its last good value, a measurement makes
the controller hold its last output (or send its fail-safe output), and a later good sample
resumes it bumplessly with ``reset(y, u held)``; a non-finite controller output is replaced
the same way; a plant input keeps its last good value.

Channels are matched by name (``output_names``, ``disturbance_names``, ``input_names``).
The reference is read again only at the instants its schedules may change
(:meth:`Reference.held_until`), and the arrays passed to the objects are made anew only when
their values change: the same values as reading and building them every tick.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import chain
from typing import Any

import numpy as np

from tank_control.core.interfaces import NS_PER_S, Controller, Plant, to_ns
from tank_control.core.ranges import Ranges
from tank_control.core.reference import Reference
from tank_control.core.trace import Trace

_FLOAT64 = np.dtype(np.float64)

Noise = Callable[[], 'np.ndarray | list[float]']
"""One measurement-noise draw per call, ordered as the plant's outputs (an array, or a list of
floats as ``MeasurementNoise.sample_floats`` gives: added as floats, the same sums)."""


@dataclass(frozen=True)
class Guards:
    """What the nodes refuse on their inputs: ``controller`` ranges (measurements, setpoints,
    measured disturbances: controller_node's ``range.*``), ``plant`` ranges (inputs and
    disturbances: plant_node's), and the controller's fail-safe: ``fail_safe_output`` (one value
    per input) sent on a bad measurement when ``hold`` is False or before any output."""

    controller: Ranges = field(default_factory=Ranges)
    plant: Ranges = field(default_factory=Ranges)
    fail_safe_output: tuple[float, ...] = ()
    hold: bool = True


def nominal_inputs(plant: Plant) -> dict[str, float]:
    """The plant's inputs before any controller output arrives (nominal operating point)."""
    return _nominal(plant, 'nominal_inputs', plant.input_names)


def nominal_disturbances(plant: Plant) -> dict[str, float]:
    """The plant's disturbances when the reference does not schedule them."""
    return _nominal(plant, 'nominal_disturbances', plant.disturbance_names)


def _nominal(plant: Plant, attr: str, names: Sequence[str]) -> dict[str, float]:
    source = getattr(plant, attr, None)
    values = source() if callable(source) else source
    if values is None:
        return {name: 0.0 for name in names}
    if isinstance(values, Mapping):
        return {name: float(values.get(name, 0.0)) for name in names}
    return {name: float(v) for name, v in zip(names, values)}


def initial_output(controller: Controller) -> np.ndarray | None:
    """The controller's documented first output (parameter ``initial_output``, one value per
    input channel, set by ``kinds.registry.build``), or None for a controller without one."""
    value = getattr(controller, 'initial_output', None)
    if value is None:
        return None
    u0 = np.asarray(value, dtype=float).reshape(-1)
    if u0.size != len(controller.input_names) or not np.all(np.isfinite(u0)):
        raise ValueError(f'initial_output: {u0.tolist()} must be {len(controller.input_names)} '
                         f'finite values, one per input {list(controller.input_names)}')
    return u0


def warm_start(controller: Controller, y: np.ndarray) -> bool:
    """Bumpless take-over at the first sample: ``controller.reset(y, initial_output)``.

    ``y`` is the first (finite) measurement of the controller's outputs. Every kind
    completes the reset at its next ``step`` (which knows ``r`` and ``d``): with
    ``y = r`` that step returns ``initial_output`` (MPCS: its equilibrium move,
    ``initial_output`` up to rounding), so a plant at its operating point with the
    setpoints there stays there. Called identically by ``run_loop`` and
    controller_node. Returns False (nothing done) for a controller without
    ``initial_output`` or a non-finite ``y`` (the first good sample warm-starts).
    """
    u0 = initial_output(controller)
    y = np.asarray(y, dtype=float)
    if u0 is None or not np.all(np.isfinite(y)):
        return False
    controller.reset(y, u0)
    return True


def sample_time_reason(plant_sample_time: float, controller_sample_time: float) -> str | None:
    """The controller samples at plant ticks: its sample time must be a positive integer
    multiple of the plant's (compared in integer nanoseconds, as the stamps are)."""
    ts_ns, cts_ns = to_ns(plant_sample_time), to_ns(controller_sample_time)
    if ts_ns <= 0 or cts_ns <= 0 or cts_ns % ts_ns:
        return (f'sample_time: the controller sample time {controller_sample_time:g} s is not a '
                f'positive integer multiple of the plant sample time {plant_sample_time:g} s')
    return None


def check_wiring(plant: Plant, controller: Controller, reference: Reference) -> None:
    """ValueError naming the first channel that cannot be connected."""
    for name in controller.output_names:
        if name not in plant.output_names:
            raise ValueError(f'controller reads output {name!r}; plant outputs: {plant.output_names}')
        if name not in reference.setpoint_names:
            raise ValueError(f'controller needs setpoint {name!r}; reference setpoint.channels: '
                             f'{reference.setpoint_names}')
    for name in controller.input_names:
        if name not in plant.input_names:
            raise ValueError(f'controller writes input {name!r}; plant inputs: {plant.input_names}')
    for name in (*reference.disturbance_names, *controller.disturbance_names):
        if name not in plant.disturbance_names:
            raise ValueError(f'disturbance {name!r} is not a plant disturbance; plant has '
                             f'{plant.disturbance_names}')


def loop_columns(plant: Plant, controller: Controller, reference: Reference) -> list[str]:
    """The column names of the rows ``iter_loop`` yields (``t`` first)."""
    return (['t'] + [f'y.{n}' for n in plant.output_names]
            + [f'r.{n}' for n in reference.setpoint_names]
            + [f'u.{n}' for n in controller.input_names]
            + [f'd.{n}' for n in reference.disturbance_names])


def loop_ticks(sample_time: float, duration: float) -> int:
    """How many ticks (rows) a run of ``duration`` seconds has: 0..K inclusive."""
    return to_ns(duration) // to_ns(sample_time) + 1


def run_loop(plant: Plant, controller: Controller, reference: Reference, *,
             sample_time: float, duration: float, noise: Noise | None = None,
             guards: Guards | None = None) -> Trace:
    """Run the closed loop for ``duration`` seconds of simulated time (ticks 0..K inclusive).

    ``sample_time`` is the plant's tick [s]; the controller's ``sample_time``
    must be an integer multiple of it. ``guards``: the nodes' refusal of implausible values
    (module docstring); None: every value passes.
    """
    rows = iter_loop(plant, controller, reference, sample_time=sample_time,
                     duration=duration, noise=noise, guards=guards)
    names = loop_columns(plant, controller, reference)
    table = np.fromiter(chain.from_iterable(rows), dtype=float)   # to the end: the last step
    return Trace.from_rows(names, table.reshape(-1, len(names)))


def iter_loop(plant: Plant, controller: Controller, reference: Reference, *,
              sample_time: float, duration: float, noise: Noise | None = None,
              guards: Guards | None = None,
              modes: Callable[[float, bool, bool], Any] | None = None
              ) -> Iterator[list[float]]:
    """``run_loop`` one row at a time (a list of floats, columns ``loop_columns``), for a
    caller that writes the rows as they come instead of holding them. The wiring and sample
    times are checked before the first row. ``modes``: called after each controller sample
    with (t [s], in manual mode, output held or fail-safe), as controller_node's monitor is
    (core/monitoring/modes.py)."""
    check_wiring(plant, controller, reference)
    reason = sample_time_reason(sample_time, controller.sample_time)
    if reason:
        raise ValueError(reason)
    if guards is not None and len(guards.fail_safe_output) != len(controller.input_names):
        raise ValueError(f'fail_safe_output: {list(guards.fail_safe_output)} must hold one value '
                         f'per input {list(controller.input_names)}')
    return _rows(plant, controller, reference, sample_time, duration, noise, guards, modes)


def _bounds(ranges: Ranges, names: Sequence[str]) -> list[tuple[float, float]] | None:
    """``(min, max)`` per channel such that ``min <= value <= max`` is
    ``ranges.accepts(name, value)``: finite bounds (a NaN fails every comparison, an infinity
    lies outside). None if a channel has no range or an infinite bound (then ``accepts``
    decides)."""
    out = []
    for name in names:
        bounds = ranges.bounds.get(name)
        if bounds is None or not (math.isfinite(bounds[0]) and math.isfinite(bounds[1])):
            return None
        out.append((bounds[0], bounds[1]))
    return out


class _Guard:
    """The refusals of :class:`Guards` as the nodes apply them (state: the last good values,
    the fault)."""

    def __init__(self, guards: Guards, plant: Plant, controller: Controller,
                 reference: Reference, u_plant: list[float], d_plant: list[float]) -> None:
        self.c, self.p = guards.controller, guards.plant
        self.fail_safe = [float(v) for v in guards.fail_safe_output]
        self.hold = guards.hold
        self.r_names = reference.setpoint_names
        self.r_good: dict[str, float] = {}
        self.d_names = plant.disturbance_names
        self.u_names = plant.input_names
        self.y_names = controller.output_names
        self.u_good = list(u_plant)
        self.d_good = list(d_plant)
        self.d_ctrl_names = controller.disturbance_names
        self.d_ctrl_good: dict[str, float] = {}
        self.u_last: list[float] | None = None      # the controller's last output
        self.fault = False
        self._y_bounds = _bounds(self.c, self.y_names)
        self._u_bounds = _bounds(self.p, self.u_names)

    def _controller_takes(self, names: Sequence[str], values: list[float],
                          good: dict[str, float]) -> list[float]:
        """Values as controller_node takes them: a refused one is its last good value (kept in
        ``good``, updated), else NaN."""
        out = []
        for name, value in zip(names, values):
            if self.c.accepts(name, value):
                good[name] = value
            out.append(good.get(name, math.nan))
        return out

    def setpoints(self, r: list[float]) -> list[float]:
        """Setpoints as controller_node takes them."""
        return self._controller_takes(self.r_names, r, self.r_good)

    def plant_inputs(self, values: list[float], good: list[float], names: Sequence[str]
                     ) -> list[float]:
        """Inputs (or disturbances) as plant_node takes them: a refused one keeps its last
        good value (``good``, updated)."""
        for i, (name, value) in enumerate(zip(names, values)):
            if self.p.accepts(name, value):
                good[i] = value
        return list(good)

    def controller_disturbances(self, d: list[float]) -> list[float]:
        """Measured disturbances as controller_node takes them."""
        return self._controller_takes(self.d_ctrl_names, d, self.d_ctrl_good)

    def sample(self, controller: Controller, t: float, y: np.ndarray, y_list: list[float],
               r: np.ndarray, d: np.ndarray, started: bool, u_plant: list[float],
               u_pos: list[int], u_whole: bool) -> tuple[list[float], np.ndarray]:
        """controller_node's sample (``_sample``), then plant_node taking its output.

        A refused measurement (``y_list``: the values of ``y``) or a non-finite output gives
        the held or fail-safe output; the first good sample after a fault resets the controller
        to the output held (bumpless), the first good sample of all warm-starts it. The output
        is written into ``u_plant`` (positions ``u_pos``; ``u_whole``: it is all of it, in
        order); the plant takes each input or keeps its last good one. Returns the output and
        the plant's inputs as an array (the controller's own array when it is that)."""
        u_out = None
        bounds = self._y_bounds
        if bounds is None:
            measured = all(self.c.accepts(name, value)
                           for name, value in zip(self.y_names, y_list))
        else:
            for (lo, hi), value in zip(bounds, y_list):
                if not lo <= value <= hi:
                    measured = False
                    break
            else:
                measured = True
        if not measured:
            u = self.held()
        else:
            if self.fault and self.u_last is not None:
                controller.reset(y, np.array(self.u_last, dtype=float))
            elif not started:
                warm_start(controller, y)
            u_out = controller.step(t, y, r, d)
            if type(u_out) is not np.ndarray or u_out.dtype is not _FLOAT64:
                u_out = np.asarray(u_out, dtype=float)
            u = u_out.tolist()
            for value in u:
                if not math.isfinite(value):
                    u, u_out = self.held(), None
                    break
            else:
                self.fault = False
                self.u_last = u
                u = list(u)
        # plant_node takes the inputs: a refused one keeps its last good value (u_good)
        whole = u_whole and len(u) == len(u_plant)
        if whole:
            u_plant[:] = u
        else:
            for i, j in enumerate(u_pos):
                u_plant[j] = u[i]
        bounds, good = self._u_bounds, self.u_good
        if bounds is None:
            taken = True
            for i, (name, value) in enumerate(zip(self.u_names, u_plant)):
                if self.p.accepts(name, value):
                    good[i] = value
                else:
                    taken = False
        else:
            taken = True
            for (lo, hi), value in zip(bounds, u_plant):
                if not lo <= value <= hi:
                    taken = False
                    break
            if taken:
                good[:] = u_plant                  # every one taken
            else:
                for i, value in enumerate(u_plant):
                    lo, hi = bounds[i]
                    if lo <= value <= hi:
                        good[i] = value
        if taken and u_out is not None and whole:
            return u, u_out                        # the values of u_plant, as the array it is
        return u, np.array(good, dtype=float)

    def held(self) -> list[float]:
        """controller_node's output on a fault: the last output (``hold``) or the fail-safe."""
        self.fault = True
        if self.hold and self.u_last is not None:
            return list(self.u_last)
        self.u_last = list(self.fail_safe)
        return list(self.fail_safe)


def _rows(plant: Plant, controller: Controller, reference: Reference, sample_time: float,
          duration: float, noise: Noise | None, guards: Guards | None = None,
          modes: Callable[[float, bool, bool], Any] | None = None) -> Iterator[list[float]]:
    ts_ns = to_ns(sample_time)
    cts_ns = to_ns(controller.sample_time)
    n_ticks = loop_ticks(sample_time, duration)

    # Signals are held as Python floats in the plant's channel order; a controller's or the
    # reference's channel writes the plant position of its name (later names win, as in a
    # dict update). The objects are called with 1-D float64 arrays, as the nodes call them; an
    # array is made anew when its values change (the objects do not modify their inputs).
    u_all = nominal_inputs(plant)
    d_all = nominal_disturbances(plant)
    u_plant = list(u_all.values())
    d_plant = list(d_all.values())
    u_pos = [plant.input_names.index(n) for n in controller.input_names]
    d_ref_pos = [plant.disturbance_names.index(n) for n in reference.disturbance_names]
    d_ctrl_pos = [plant.disturbance_names.index(n) for n in controller.disturbance_names]
    y_index = [plant.output_names.index(n) for n in controller.output_names]
    r_index = [reference.setpoint_names.index(n) for n in controller.output_names]
    y_whole = y_index == list(range(len(plant.output_names)))       # y[y_index] is y
    r_whole = r_index == list(range(len(reference.setpoint_names)))
    u_whole = u_pos == list(range(len(plant.input_names)))          # u of the plant is u_ctrl
    u_ctrl = [u_all[n] for n in controller.input_names]
    u_arr = np.array(u_plant, dtype=float)
    d_arr = np.array(d_plant, dtype=float)
    d_ctrl = np.array([d_plant[j] for j in d_ctrl_pos], dtype=float)
    r_row: list[float] = []
    r_all = np.empty(0)
    d_ref: list[float] = []
    r_until = d_until = -math.inf      # the schedules hold their values before these instants
    held_until = reference.held_until
    started = False
    values, outputs, plant_step = reference.values, plant.outputs, plant.step
    controller_step = controller.step
    isfinite = math.isfinite
    guard = (None if guards is None else
             _Guard(guards, plant, controller, reference, u_plant, d_plant))
    for k in range(n_ticks):
        t_ns = k * ts_ns
        t = t_ns / NS_PER_S                      # seconds(t_ns)
        if t >= r_until:
            r_now = values('setpoint', t)        # the values of reference.setpoints(t)
            r_until = held_until('setpoint', t)
            if k == 0 or r_now != r_row:
                r_row = r_now
                r_all = np.array(r_row if guard is None else guard.setpoints(r_row), dtype=float)
        if d_ref_pos and t >= d_until:
            d_now = values('disturbance', t)
            d_until = held_until('disturbance', t)
            if d_now != d_ref:
                d_ref = d_now
                for i, j in enumerate(d_ref_pos):
                    d_plant[j] = d_ref[i]
                if guard is None:
                    d_arr = np.array(d_plant, dtype=float)
                    d_ctrl = np.array([d_plant[j] for j in d_ctrl_pos], dtype=float)
                else:
                    d_ctrl = np.array(guard.controller_disturbances(
                        [d_plant[j] for j in d_ctrl_pos]), dtype=float)
                    d_arr = np.array(guard.plant_inputs(d_plant, guard.d_good, guard.d_names),
                                     dtype=float)
        y = outputs()
        if noise is None:
            y_row = y.tolist()
        else:
            n_row = noise()
            if (type(n_row) is list and type(y) is np.ndarray and y.dtype is _FLOAT64
                    and len(n_row) == len(y)):
                y_row = y.tolist()
                if any(n_row) or 0.0 in y_row:
                    y_row = [a + b for a, b in zip(y_row, n_row)]    # y + noise, as floats
                    y = np.array(y_row, dtype=float)
                # else the noise is all zeros and y has no zero: y + noise is y, bit for bit
            else:
                y = y + np.asarray(n_row, dtype=float)
                y_row = y.tolist()
        if t_ns % cts_ns == 0 and guard is not None:
            u_ctrl, u_arr = guard.sample(
                controller, t, y if y_whole else y[y_index],
                y_row if y_whole else [y_row[i] for i in y_index],
                r_all if r_whole else r_all[r_index], d_ctrl, started, u_plant, u_pos, u_whole)
            started = True
        elif t_ns % cts_ns == 0:
            y_c = y if y_whole else y[y_index]
            if not started and all(isfinite(y_row[i]) for i in y_index):
                warm_start(controller, y_c)      # the first good sample: bumpless take-over
                started = True
            u_out = controller_step(t, y_c, r_all if r_whole else r_all[r_index], d_ctrl)
            if type(u_out) is not np.ndarray or u_out.dtype is not _FLOAT64:
                u_out = np.asarray(u_out, dtype=float)
            u_ctrl = u_out.tolist()
            if u_whole and len(u_ctrl) == len(u_plant):
                u_arr = u_out
            else:
                for i, j in enumerate(u_pos):
                    u_plant[j] = u_ctrl[i]
                u_arr = np.array(u_plant, dtype=float)
        if modes is not None and t_ns % cts_ns == 0:
            modes(t, controller.status.get('mode') == 'manual',
                  guard is not None and guard.fault)
        yield [t, *y_row, *r_row, *u_ctrl, *d_ref]
        plant_step(u_arr, d_arr, sample_time)
