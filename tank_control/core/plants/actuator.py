"""Actuator faults between the controller and every plant kind's inputs (parameters ``actuator.*``).

Per input channel, in this order, on each plant step (the plant sees the result as its ZOH input):

1. rate limit ``actuator.rate_limit`` r [input units/s]: the actuator position moves toward the
   command by at most ``r·dt`` per step (0 = none);
2. stiction, the two-parameter data-driven model of [Choudhury2005] (``actuator.stiction_s`` S =
   deadband + stickband, ``actuator.stiction_j`` J = slip jump, input units; S = 0 = none):
   the valve sticks when its input stops (zero change over a step) or reverses; stuck at the
   input value ``u_s`` after moving in direction ``d``, it slips when the input has moved past
   ``u_s`` by more than J in direction ``d`` or by more than S against it; moving, it sits at
   ``x = u − d·(S − J)/2``. So a reversal is followed by a flat stretch of S and a jump of J;
   J = 0 is a pure deadband of width S, S = J stick-slip without offset, J > S overshoot.
   Unlike the paper's flowchart ``u_s`` is where the valve stuck and is not moved by input
   reversals inside the band (a stuck valve's force grows with the distance from where it
   stopped). At the first step the valve is at rest at the input with no known direction (a
   first movement needs S);
3. backlash ``actuator.deadband`` b [input units] (a play operator): the output follows the input
   when they differ by more than b/2, keeping that distance, else holds (0 = none).

Each parameter takes one value for every input channel or one per input (as ``noise_std`` does per
output). All off by default: then the plant is not wrapped at all. Read-only (set at start-up).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.interfaces import Plant, StatusValue
from tank_control.core.params import ConfigError, param

_FIELDS = ('rate_limit', 'stiction_s', 'stiction_j', 'deadband')


@dataclass(frozen=True)
class ActuatorConfig:
    """Actuator faults per plant input channel ([Choudhury2005] stiction, backlash, rate limit)."""

    stiction_s: tuple[float, ...] = param(
        (0.0,), 'stiction S (deadband plus stickband) per input channel of the two-parameter '
        'model [Choudhury2005]; one value applies to every input; 0 = no stiction',
        unit='input units', min=0.0, max=1e12, read_only=True, name='actuator.stiction_s')
    stiction_j: tuple[float, ...] = param(
        (0.0,), 'stiction slip jump J per input channel [Choudhury2005] (J = 0 with S > 0: a '
        'pure deadband of width S; J = S: stick-slip without offset; J > S: overshoot)',
        unit='input units', min=0.0, max=1e12, read_only=True, name='actuator.stiction_j')
    deadband: tuple[float, ...] = param(
        (0.0,), 'backlash (play) width per input channel: the actuator holds until the input '
        'has moved by it after a reversal; 0 = none', unit='input units', min=0.0, max=1e12,
        read_only=True, name='actuator.deadband')
    rate_limit: tuple[float, ...] = param(
        (0.0,), 'largest rate of change of the actuator position per input channel; 0 = none',
        unit='input units/s', min=0.0, max=1e12, read_only=True, name='actuator.rate_limit')

    def active(self) -> bool:
        """True if any fault is on."""
        return any(v > 0.0 for f in ('rate_limit', 'stiction_s', 'deadband')
                   for v in getattr(self, f))

    def vectors(self, names: Sequence[str]) -> dict[str, np.ndarray]:
        """Each field as one value per input channel ``names``; ``ConfigError`` naming the
        parameter for a wrong count."""
        n = len(names)
        out = {}
        for f in _FIELDS:
            values = np.asarray(getattr(self, f), dtype=float).reshape(-1)
            if values.size == 1:
                values = np.full(n, values[0])
            if values.size != n:
                raise ConfigError(f'actuator.{f}: {values.size} values for {n} input channels '
                                  f'{list(names)}; give ' + ('1' if n == 1 else f'1 or {n}'))
            out[f] = values
        return out


class ActuatorChain:
    """The actuator state of every input channel; :meth:`apply` maps commands to positions."""

    def __init__(self, config: ActuatorConfig, names: Sequence[str]) -> None:
        v = config.vectors(names)
        self.names = tuple(names)
        self.rate = v['rate_limit']
        self.s = v['stiction_s']
        self.j = np.where(self.s > 0.0, v['stiction_j'], 0.0)
        self.band = v['deadband']
        self.reset()

    def reset(self) -> None:
        n = len(self.names)
        self._started = False
        self._rated = np.zeros(n)          # rate-limited command
        self._u_prev = np.zeros(n)         # stiction input of the previous step
        self._x = np.zeros(n)              # stiction output (valve position)
        self._stuck = np.ones(n, dtype=bool)
        self._u_s = np.zeros(n)            # input where the valve stuck
        self._dir = np.zeros(n)            # last direction of motion (0: none yet)
        self._out = np.zeros(n)            # backlash output
        self.stuck_steps = 0               # steps with some stiction channel stuck

    def apply(self, u: np.ndarray, dt: float) -> np.ndarray:
        """The actuator positions the plant sees over the next step of ``dt`` [s]."""
        u = np.asarray(u, dtype=float)
        if not self._started:
            self._started = True
            self._rated = u.copy()
            self._u_prev = u.copy()
            self._x = u.copy()
            self._u_s = u.copy()
            self._out = u.copy()
            return u.copy()
        # 1. rate limit
        rated = u.copy()
        limited = self.rate > 0.0
        if limited.any():
            step = self.rate * dt
            rated[limited] = self._rated[limited] + np.clip(
                u[limited] - self._rated[limited], -step[limited], step[limited])
        self._rated = rated
        # 2. stiction [Choudhury2005]
        x = rated.copy()
        for i in np.flatnonzero(self.s > 0.0):
            x[i] = self._stiction(int(i), float(rated[i]))
        # 3. backlash
        out = x.copy()
        for i in np.flatnonzero(self.band > 0.0):
            half = self.band[i] / 2.0
            gap = x[i] - self._out[i]
            out[i] = x[i] - half if gap > half else x[i] + half if gap < -half else self._out[i]
        self._out = out
        return out

    def _stiction(self, i: int, u: float) -> float:
        s, j = float(self.s[i]), float(self.j[i])
        change = u - self._u_prev[i]
        moving_dir = float(np.sign(change))
        if not self._stuck[i]:
            if moving_dir == 0.0 or moving_dir != self._dir[i]:   # stops or reverses: sticks
                self._stuck[i] = True
                self._u_s[i] = self._u_prev[i]
        if self._stuck[i]:
            travel = u - self._u_s[i]
            along = self._dir[i] != 0.0 and np.sign(travel) == self._dir[i]
            if abs(travel) > (j if along else s):
                self._stuck[i] = False
                self._dir[i] = float(np.sign(travel))
                self._x[i] = u - self._dir[i] * (s - j) / 2.0
            else:
                self.stuck_steps += 1
        else:
            self._x[i] = u - self._dir[i] * (s - j) / 2.0
        self._u_prev[i] = u
        return float(self._x[i])


class ActuatedPlant:
    """A plant whose inputs pass through :class:`ActuatorChain` first (everything else is the
    wrapped plant's: outputs, disturbances, ``configure``, attributes)."""

    def __init__(self, plant: Plant, config: ActuatorConfig) -> None:
        self._plant = plant
        self.actuator = ActuatorChain(config, plant.input_names)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._plant, name)

    @property
    def output_names(self) -> tuple[str, ...]:
        return self._plant.output_names

    @property
    def input_names(self) -> tuple[str, ...]:
        return self._plant.input_names

    @property
    def disturbance_names(self) -> tuple[str, ...]:
        return self._plant.disturbance_names

    def reset(self) -> None:
        self._plant.reset()
        self.actuator.reset()

    def outputs(self) -> np.ndarray:
        return self._plant.outputs()

    def step(self, u: np.ndarray, d: np.ndarray, dt: float) -> None:
        self._plant.step(self.actuator.apply(u, dt), d, dt)

    @property
    def status(self) -> Mapping[str, StatusValue]:
        """The plant's status and ``actuator_stuck_steps``."""
        return {**self._plant.status, 'actuator_stuck_steps': self.actuator.stuck_steps}


def with_actuator(plant: Plant, config: ActuatorConfig) -> Plant:
    """``plant`` itself when no fault is on, else wrapped in :class:`ActuatedPlant`."""
    if not config.active():
        return plant
    return ActuatedPlant(plant, config)
