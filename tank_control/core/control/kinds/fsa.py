"""Controller kind ``fsa``: finite spectrum assignment with integral action for a stable or
unstable first-order plant with dead time ([Precup2013] §3.6.2, eqs. 3.6.10–3.6.15)."""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.linear import LinearController, RationalModel
from tank_control.core.control.fsa import FsaConfig, FsaController, transfer_polynomials
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, Settings

MODEL = ('fsa.model', 'fsa.gain', 'fsa.time_constant', 'fsa.dead_time')
"""The internal model: a change rebuilds the controller (bumpless, the input history restarts
at the steady state of the last output)."""
FIELDS = {'fsa.omega0': 'omega0', 'fsa.xi': 'xi', 'u_min': 'u_min', 'u_max': 'u_max',
          'anti_windup': 'anti_windup', 'tracking_time': 'tracking_time'}
"""Parameters changed in place (bumplessly) by their field names."""

MAX_ANALYSED_DELAY = 2000
"""Largest dead time in samples whose loop is analysed (the transfer function's degree)."""


def build(settings: Settings) -> FsaController:
    controller = FsaController(settings.config, output_name=settings.channels.output_names[0],
                               input_name=settings.channels.input_names[0])
    if settings.mode.mode == 'manual':
        controller.set_manual(float(settings.mode.manual_output))
    return controller


def update(controller: FsaController, settings: Settings, changed: frozenset[str]) -> bool:
    """``fsa.omega0``, ``fsa.xi``, limits and anti-windup in place (the integral absorbs the
    change), then the mode; a change of the model (``fsa.model``, ``fsa.gain``,
    ``fsa.time_constant``, ``fsa.dead_time``) rebuilds."""
    if any(name in MODEL for name in changed):
        return False
    running, new = controller.config, settings.config
    changes = {field: getattr(new, field) for field in FIELDS.values()
               if getattr(running, field) != getattr(new, field)}
    if changes:
        controller.set_gains(**changes)
    base.apply_mode(controller, controller.mode, settings, changed)
    return True


def linear(settings: Settings) -> LinearController | None:
    """The implemented law's transfer functions (:func:`fsa.transfer_polynomials`: the FIR
    prediction sums and the integral, gain magnitude) and the internal model; None when the
    dead time is more than :data:`MAX_ANALYSED_DELAY` samples (the polynomials' degree)."""
    config = settings.config
    if config.dead_time / config.sample_time > MAX_ANALYSED_DELAY:
        return None
    config = replace(config, gain=abs(config.gain))
    (num, den), (num_r, _) = transfer_polynomials(config)
    h = config.sample_time
    model: Any
    if config.model == 'foupdt':
        model = RationalModel((config.gain,), (config.time_constant, -1.0), config.dead_time,
                              'foupdt')
    else:
        model = ProcessModel('fopdt', config.gain, config.dead_time, config.time_constant)
    with np.errstate(invalid='ignore', divide='ignore'):
        feedback = fr.rational_discrete(num, den, h)
        setpoint = fr.rational_discrete(num_r, den, h)
    return LinearController(feedback, f'FSA w0 {config.omega0:.4g} rad/s, xi {config.xi:.3g}',
                            setpoint, models=(('internal', model),))


def reason(settings: Settings) -> str | None:
    return base.siso_reason(settings)


KIND = ControllerKind(
    name='fsa',
    description='finite spectrum assignment (predictor state feedback with integral action) '
                'for K/(T s +- 1) e^(-L s), poles of p(s) = s^2 + 2 xi w0 s + w0^2 '
                '([Precup2013] §3.6.2)',
    config=FsaConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start()),
    build=build, update=update, reason=reason,
    gains=('fsa.omega0', 'fsa.xi'),
    input_limits=base.scalar_limits, linear=linear,
)
