"""Controller kind ``on_off``: an on/off (two-position) controller with hysteresis.

The output is ``u_max`` (on) while the error ``e = r − y`` (``y − r`` with
``direct_action``) is above ``hysteresis/2``, ``u_min`` (off) while it is below
``−hysteresis/2``; inside the band it keeps its last output. That last rule makes it
bumpless: after ``reset(y, u)``, a return from manual or a rebuild, the output stays where it
was until the error leaves the band. Non-finite inputs hold the last output.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.params import param


@dataclass(frozen=True)
class OnOffConfig:
    """The parameters (each field is one, declared once with its range and unit)."""

    sample_time: float = param(1.0, 'controller sample time', unit='s', min=1e-3, max=3600.0)
    u_min: float = param(0.0, 'output when off (lower output limit)', unit='u units',
                         min=-1e9, max=1e9)
    u_max: float = param(100.0, 'output when on (upper output limit)', unit='u units',
                         min=-1e9, max=1e9)
    hysteresis: float = param(1.0, 'width of the band around the setpoint in which the output '
                              'does not switch', unit='y units', min=0.0, max=1e9)
    direct_action: bool = param(False, 'true: on when y is above the setpoint (cooling)')

    def reason(self) -> str | None:
        """Relations between fields: one line naming the parameter, or None."""
        if not self.u_min < self.u_max:
            return (f'u_max: {self.u_max:g} must be above u_min {self.u_min:g}; allowed '
                    f'({self.u_min:g}, 1e9]')
        return None


class OnOffController:
    """The law behind tank_control's Controller protocol (SISO)."""

    disturbance_names: tuple[str, ...] = ()

    def __init__(self, config: OnOffConfig, output_name: str = 'y', input_name: str = 'u'):
        self.config = config
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self._u = config.u_min
        self._mode = 'auto'
        self._manual: float | None = None
        self._switches = 0

    @property
    def sample_time(self) -> float:
        return self.config.sample_time

    @property
    def mode(self) -> str:
        return self._mode

    @property
    def status(self) -> dict[str, Any]:
        return {'mode': self._mode, 'on': self._u == self.config.u_max, 'u': self._u,
                'switches': self._switches}

    def _clip(self, u: float) -> float:
        return min(max(u, self.config.u_min), self.config.u_max)

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        value = float(np.asarray(u, dtype=float).reshape(-1)[0])
        if math.isfinite(value):
            self._u = self._clip(value)

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        if self._mode == 'manual':
            self._u = self._clip(self._manual if self._manual is not None else self._u)
            return np.array([self._u])
        e = float(r[0]) - float(y[0])
        if self.config.direct_action:
            e = -e
        half = 0.5 * self.config.hysteresis
        u = self._u
        if e > half:
            u = self.config.u_max
        elif e < -half:
            u = self.config.u_min
        u = self._clip(u)                        # limits changed live: the output follows
        if math.isfinite(e) and u != self._u:
            self._switches += 1
        if math.isfinite(e):
            self._u = u
        return np.array([self._u])

    def set_manual(self, u: float) -> None:
        self._manual, self._mode = float(u), 'manual'

    def set_auto(self) -> None:
        self._mode = 'auto'                      # the output stays until the error leaves the band


def build(settings: Settings) -> OnOffController:
    controller = OnOffController(settings.config, settings.channels.output_names[0],
                                 settings.channels.input_names[0])
    if settings.mode.mode == 'manual':
        controller.set_manual(float(settings.mode.manual_output))
    return controller


def update(controller: OnOffController, settings: Settings, changed: frozenset[str]) -> bool:
    """Every change in place: the new settings act from this sample, the output is kept."""
    controller.config = settings.config
    base.apply_mode(controller, controller.mode, settings, changed)
    return True


KIND = ControllerKind(
    name='on_off',
    description='on/off controller with hysteresis (example package tank-heater-kinds)',
    config=OnOffConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start()),
    build=build, update=update, reason=base.siso_reason,
    results=lambda c: {},
    gains=('hysteresis',), input_limits=base.scalar_limits,
)
