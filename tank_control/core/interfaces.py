"""The small interfaces every plant, controller and reference shares.

These are the contracts between `core/` objects, `core/loop.py` (the in-process
closed loop) and the ROS 2 nodes. Everything here is pure Python/numpy.

Conventions
-----------
* Signals are named channels. A plant declares the names of its measured
  outputs, manipulated inputs and disturbances; a controller declares which
  outputs it reads and which inputs it writes; setpoints carry the name of the
  output they are for (a setpoint for ``h`` is named ``h``).
* SISO plants use the channel names ``y`` (output), ``u`` (manipulated input)
  and ``v`` (load disturbance at the plant input, 000 Fig. 1: y = G·(u + v)).
* The mixing tank (003 §1) uses outputs ``h`` [cm], ``T_out`` [°C]; inputs
  ``F_H``, ``F_Cin`` [cm³/s]; disturbances ``F_D`` [cm³/s], ``T_D``, ``T_H``,
  ``T_C`` [°C]. Units are those of the document (cm, cm³/s, °C, s).
* Vectors are 1-D ``numpy.float64`` arrays ordered as the declared names.
* Time is kept as integer nanoseconds (``t_ns``) wherever samples are counted,
  so that the in-process loop and the ROS graph (whose stamps are integer
  nanoseconds) see bit-identical sample instants; ``seconds(t_ns)`` converts.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np

NS_PER_S = 1_000_000_000

StatusValue = bool | int | float | str


def to_ns(seconds_value: float) -> int:
    """Round a duration in seconds to integer nanoseconds."""
    return int(round(seconds_value * NS_PER_S))


def seconds(t_ns: int) -> float:
    """Integer nanoseconds to float seconds (the one conversion used everywhere)."""
    return t_ns / NS_PER_S


@runtime_checkable
class Plant(Protocol):
    """A simulated process advanced with zero-order-hold inputs."""

    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    disturbance_names: tuple[str, ...]

    def reset(self) -> None:
        """Return to the initial state (clears delay-line history)."""

    def outputs(self) -> np.ndarray:
        """Noise-free outputs at the current instant, ordered as ``output_names``."""

    def step(self, u: np.ndarray, d: np.ndarray, dt: float) -> None:
        """Advance by ``dt`` seconds with ``u`` and ``d`` held constant (ZOH)."""

    @property
    def status(self) -> Mapping[str, StatusValue]:
        """Counters and flags for diagnostics (e.g. clipped flows, overflow)."""


@runtime_checkable
class Controller(Protocol):
    """A discrete-time controller sampled every ``sample_time`` seconds.

    ``step`` is called exactly once per sample with the measurement of that
    instant; it returns the manipulated inputs to hold until the next sample.
    """

    output_names: tuple[str, ...]       # measured channels it reads (= setpoint names)
    input_names: tuple[str, ...]        # manipulated channels it writes
    disturbance_names: tuple[str, ...]  # measured disturbances it may use (feed-forward)
    sample_time: float

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        """Initialise bumplessly: the next output continues from ``u``."""

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        """One sample: time [s], measurement, setpoint, measured disturbance → inputs."""

    @property
    def status(self) -> Mapping[str, Any]:
        """Read-only view for diagnostics (mode, saturation, anti-windup, ...)."""
