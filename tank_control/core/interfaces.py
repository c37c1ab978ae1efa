"""The small interfaces every plant, controller and reference shares (pure Python/numpy).

The contracts between ``core/`` objects, ``core/loop.py`` and the ROS 2 nodes. Signals are
named channels: a plant declares its outputs, inputs and disturbances, a controller the outputs
it reads and the inputs it writes, a setpoint carries its output's name. SISO plants use ``y``,
``u`` and ``v`` (load at the plant input, [Viteckova] Fig. 1); the mixing tank ([Michalski2021] §1) ``h`` [cm],
``T_out`` [°C], ``F_H``, ``F_Cin``, ``F_D`` [cm³/s], ``T_D``, ``T_H``, ``T_C`` [°C]. Vectors
are 1-D float64 arrays in the declared order. Time is integer nanoseconds wherever samples are
counted, so the in-process loop and the ROS graph see bit-identical instants;
``seconds(t_ns)`` converts.
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

    @property
    def output_names(self) -> tuple[str, ...]:
        """Its measured channels."""

    @property
    def input_names(self) -> tuple[str, ...]:
        """Its manipulated inputs."""

    @property
    def disturbance_names(self) -> tuple[str, ...]:
        """Its disturbance inputs."""

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
class Configurable(Protocol):
    """A plant with live changes (optional, docs/extending.md)."""

    def configure(self, **changes: Any) -> None:
        """Change parameters (all or nothing) from the next ``step``; ``ValueError`` names a
        refused one (e.g. a read-only parameter)."""


@runtime_checkable
class Controller(Protocol):
    """A discrete-time controller sampled every ``sample_time`` seconds.

    ``step`` is called exactly once per sample with the measurement of that
    instant; it returns the manipulated inputs to hold until the next sample.
    """

    # read-only members (a class attribute, an instance attribute or a property of any of them)
    @property
    def output_names(self) -> tuple[str, ...]:
        """Measured channels it reads (= setpoint names)."""

    @property
    def input_names(self) -> tuple[str, ...]:
        """Manipulated channels it writes."""

    @property
    def disturbance_names(self) -> tuple[str, ...]:
        """Measured disturbances it may use (feed-forward)."""

    @property
    def sample_time(self) -> float:
        """[s]"""

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        """Initialise bumplessly: the next output continues from ``u``."""

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        """One sample: time [s], measurement, setpoint, measured disturbance → inputs."""

    @property
    def status(self) -> Mapping[str, Any]:
        """Read-only view for diagnostics (mode, saturation, anti-windup, ...)."""
