"""Test helpers for the relay auto-tuner (no tests here): an exact dead-time plant,
the exact ultimate point solved independently, and small closed loops.

The plant is exact for ZOH inputs and any dead time (not only multiples of the
sample time): the delayed input is a queue of (time it takes effect, value) and
the first-order state is advanced analytically between breakpoints.
"""
from __future__ import annotations

import collections
import math
from collections.abc import Callable

import numpy as np


class ExactDelayPlant:
    """``gain/(time_constant·s + 1)·e^(−dead_time·s)`` (FOPDT, [Checks] §1) or, with
    ``time_constant=None``, ``gain/s·e^(−dead_time·s)`` (IPDT, [Viteckova] eq. 1); starts at
    rest at output ``y0`` with input ``u0`` applied for ever."""

    output_names = ('y',)
    input_names = ('u',)
    disturbance_names = ('v',)
    status: dict = {}

    def __init__(self, gain: float, time_constant: float | None, dead_time: float,
                 y0: float = 0.0, u0: float = 0.0) -> None:
        self.gain, self.time_constant, self.dead_time = gain, time_constant, dead_time
        self.y0, self.u0 = y0, u0
        self.reset()

    def reset(self) -> None:
        self.t = 0.0
        self.x = self.y0
        self.current = self.u0
        self.queue: collections.deque = collections.deque()

    def outputs(self) -> np.ndarray:
        return np.array([self.x])

    def _advance(self, h: float, v: float) -> None:
        if h <= 0.0:
            return
        if self.time_constant is None:
            self.x += self.gain * (v - self.u0) * h
        else:
            target = self.y0 + self.gain * (v - self.u0)
            self.x = target + (self.x - target) * math.exp(-h / self.time_constant)

    def step(self, u: np.ndarray, d: np.ndarray, dt: float) -> None:
        value = float(u[0]) + (float(d[0]) if len(d) else 0.0)
        self.queue.append((self.t + self.dead_time, value))
        t, t_end = self.t, self.t + dt
        while self.queue and self.queue[0][0] <= t_end + 1e-12:
            t_eff, v = self.queue.popleft()
            self._advance(t_eff - t, self.current)
            t = max(t, t_eff)
            self.current = v
        self._advance(t_end - t, self.current)
        self.t = t_end


def exact_fopdt_ultimate(gain: float, time_constant: float, dead_time: float) -> tuple[float, float]:
    """Ku, Tu of an FOPDT solved here by bisection of ``ω·L + arctan(ω·T) = π`` on (0, π/L)."""
    lo, hi = 0.0, math.pi / dead_time
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid * dead_time + math.atan(mid * time_constant) < math.pi:
            lo = mid
        else:
            hi = mid
    w = 0.5 * (lo + hi)
    return math.sqrt(1.0 + (w * time_constant) ** 2) / gain, 2.0 * math.pi / w


def exact_ipdt_ultimate(k1: float, dead_time: float) -> tuple[float, float]:
    """[Checks] §1: Ku = π/(2·k1·To), Tu = 4·To."""
    return math.pi / (2.0 * k1 * dead_time), 4.0 * dead_time


def relay_record(plant: ExactDelayPlant, d: float, hysteresis: float, noise_std: float,
                 sample_time: float, samples: int, seed: int = 0, bias: float = 0.0,
                 setpoint: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A plain relay loop ([Precup2013] Fig. 3.1/3.3): u = u0 + bias ± d switched by e = r − y with
    hysteresis; the measurement carries seeded white noise. Returns t, u, y (measured)."""
    rng = np.random.default_rng(seed)
    u0 = plant.u0
    high = True
    t, u, y = np.zeros(samples), np.zeros(samples), np.zeros(samples)
    for k in range(samples):
        ym = plant.outputs()[0] + noise_std * rng.standard_normal()
        e = setpoint - ym
        if e > hysteresis:
            high = True
        elif e < -hysteresis:
            high = False
        uk = u0 + bias + (d if high else -d)
        t[k], u[k], y[k] = k * sample_time, uk, ym
        plant.step(np.array([uk]), np.array([0.0]), sample_time)
    return t, u, y


def closed_loop(controller, plant: ExactDelayPlant, setpoint: Callable[[float], float] | float,
                samples: int, noise_std: float = 0.0, seed: int = 0,
                before_step: Callable[[int, float], None] | None = None,
                measurement: Callable[[int, float], float] | None = None) -> dict[str, np.ndarray]:
    """Run controller and plant for ``samples`` controller samples (plant step = controller
    sample time). ``before_step(k, t)`` may act on the controller (start, abort);
    ``measurement(k, y)`` may corrupt the measured value. Returns t, y, r, u and state."""
    rng = np.random.default_rng(seed)
    ts = controller.sample_time
    out: dict[str, list] = {'t': [], 'y': [], 'r': [], 'u': [], 'state': []}
    for k in range(samples):
        t = k * ts
        y = plant.outputs()[0] + noise_std * rng.standard_normal()
        if measurement is not None:
            y = measurement(k, y)
        r = setpoint(t) if callable(setpoint) else setpoint
        if before_step is not None:
            before_step(k, t)
        u = float(controller.step(t, np.array([y]), np.array([r]), np.zeros(0))[0])
        for key, value in zip(('t', 'y', 'r', 'u', 'state'), (t, y, r, u, controller.state)):
            out[key].append(value)
        plant.step(np.array([u]), np.zeros(1), ts)
    return {k: np.array(v) for k, v in out.items()}


def run_logged(params: dict, duration: float, reset: tuple[float, float] | None = None):
    """Run ``params`` (a relay_autotune scenario) in-process for ``duration`` [s]; returns
    (trace, the built objects, [(t, state) at each change of the tuner's state])."""
    from tank_control.core.loop import run_loop
    from tank_control.core.scenario import build
    built = build(params)
    tuner = built.controller
    if reset is not None:
        tuner.reset(np.array([reset[0]]), np.array([reset[1]]))
    log: list[tuple[float, str]] = []
    step = tuner.step

    def logged(t, y, r, d):
        u = step(t, y, r, d)
        if not log or log[-1][1] != tuner.state:
            log.append((t, tuner.state))
        return u
    tuner.step = logged
    trace = run_loop(built.plant, tuner, built.reference, sample_time=built.sample_time,
                     duration=duration, noise=built.noise.sample)
    return trace, built, log
