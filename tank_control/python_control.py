"""Round trips with python-control (the optional extra ``pip install .[control]``).

The project keeps dead time exact (``core/analysis/frequency.py``, ``core/plants``);
python-control represents it as a Padé approximation in a rational transfer function or
exactly as frequency-response data. Both directions:

- :func:`to_transfer_function` — a process model (``core/tuning/model.ProcessModel``), a
  ``transfer_function`` plant's settings or (num, den, dead time) as ``control.TransferFunction``
  with the dead time as a Padé approximant of ``pade_order`` (``control.pade``);
- :func:`to_frequency_data` — any of those, or one of the project's ``FrequencyResponse``
  objects (a loop, a controller), as ``control.FrequencyResponseData`` with the exact delay on a
  frequency grid [rad/s];
- :func:`pid_transfer_function` — the project's continuous PID feedback law
  ``kp·(1 + 1/(ti·s) + td·s/(1 + td·s/n))`` (``frequency.pid_feedback``);
- :func:`controller_transfer_function` / :func:`controller_state_space` — a controller kind's
  linear description (``ControllerKind.linear``: the implemented discrete law ``−U/Y``, or its
  setpoint path ``U/R``) as a discrete ``control.TransferFunction`` / ``StateSpace`` with
  ``dt`` = the controller's sample time, exact (from the description's own coefficients,
  ``FrequencyResponse.coefficients``), e.g. from a scenario's controller parameters;
- :func:`plant_settings` — a continuous SISO ``control.TransferFunction`` plus a dead time [s]
  as the parameters of ``plant: transfer_function`` (``num``, ``den``, ``dead_time``), e.g. for
  ``tank_control.core.plants.transfer_function.TransferFunctionConfig(**plant_settings(G, L))``
  or a scenario's plant parameters.

python-control is imported here only: the rest of the project does not need it. Times in s,
frequencies in rad/s.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from tank_control.core.analysis import frequency as fr

PADE_ORDER = 6
"""Default order of the Padé approximant of the dead time (a 6th order one is within 1° of
the exact phase up to ω·L ≈ 8)."""


def _control() -> Any:
    try:
        import control
    except ImportError as exc:          # the extra is not installed
        raise ImportError("python-control is not installed; install the extra with "
                          "`pip install .[control]` (or `pip install control`)") from exc
    return control


def _rational(source: Any) -> tuple[list[float], list[float], float]:
    """(num, den, dead time) of a process model, transfer_function settings or a triple."""
    if hasattr(source, 'numerator_denominator'):              # ProcessModel
        num, den = source.numerator_denominator()
        return list(num), list(den), float(source.dead_time)
    if hasattr(source, 'num') and hasattr(source, 'den'):     # TransferFunctionConfig
        return list(source.num), list(source.den), float(getattr(source, 'dead_time', 0.0))
    if isinstance(source, (tuple, list)) and len(source) == 3:
        num, den, dead_time = source
        return list(num), list(den), float(dead_time)
    raise TypeError(f'{type(source).__name__}: not a process model, transfer_function '
                    'settings or (num, den, dead_time)')


def to_transfer_function(source: Any, pade_order: int = PADE_ORDER) -> Any:
    """``control.TransferFunction`` of ``source`` with its dead time as a Padé approximant of
    ``pade_order`` (0: the delay is dropped, which the caller must mean)."""
    control = _control()
    num, den, dead_time = _rational(source)
    g = control.tf(num, den)
    if dead_time > 0.0 and pade_order > 0:
        g = g * control.tf(*control.pade(dead_time, pade_order))
    return g


def to_frequency_data(source: Any, omega: Sequence[float] | np.ndarray | None = None) -> Any:
    """``control.FrequencyResponseData`` with the exact dead time on ``omega`` [rad/s]
    (default: the project's grid for the response, ``frequency.default_grid``)."""
    control = _control()
    if isinstance(source, fr.FrequencyResponse):
        response = source
    else:
        num, den, dead_time = _rational(source)
        response = fr.rational(num, den, dead_time)
    w = fr.default_grid(response) if omega is None else np.asarray(omega, dtype=float)
    return control.frd(response(w), w)


def pid_transfer_function(kp: float, ti: float = math.inf, td: float = 0.0,
                          n: float = 10.0) -> Any:
    """The continuous feedback law ``kp·(1 + 1/(ti·s) + td·s/(1 + td·s/n))`` (ti = inf: no
    integral action; td = 0: no derivative), as ``frequency.pid_feedback``."""
    control = _control()
    s = control.tf('s')
    c = control.tf([kp], [1.0])
    if math.isfinite(ti) and ti > 0.0:
        c = c + kp / (ti * s)
    if td > 0.0:
        c = c + kp * td * s / (1.0 + td * s / n)
    return control.minreal(c, verbose=False) if (td > 0.0 or math.isfinite(ti)) else c


def plant_settings(g: Any, dead_time: float = 0.0) -> dict[str, Any]:
    """The ``transfer_function`` plant's parameters for a continuous SISO
    ``control.TransferFunction`` ``g`` and ``dead_time`` [s]; ValueError with the reason for a
    discrete, MIMO or not strictly proper ``g`` or a negative dead time."""
    control = _control()
    if not isinstance(g, control.TransferFunction):
        raise ValueError(f'plant: {type(g).__name__} is not a control.TransferFunction')
    if g.ninputs != 1 or g.noutputs != 1:
        raise ValueError(f'plant: {g.noutputs}×{g.ninputs} system; a plant from python-control '
                         'is SISO')
    if g.dt not in (0, None):
        raise ValueError(f'plant: discrete (dt = {g.dt}); the plant needs a continuous '
                         'transfer function')
    if not (math.isfinite(dead_time) and dead_time >= 0.0):
        raise ValueError(f'dead_time: {dead_time!r} must be a finite number >= 0')
    num = np.trim_zeros(np.atleast_1d(np.asarray(g.num[0][0], dtype=float)), 'f')
    den = np.trim_zeros(np.atleast_1d(np.asarray(g.den[0][0], dtype=float)), 'f')
    if len(num) >= len(den):
        raise ValueError(f'plant: num degree {len(num) - 1} >= den degree {len(den) - 1}; the '
                         'transfer_function plant needs a strictly proper G(s)')
    return {'plant': 'transfer_function', 'num': [float(v) for v in num],
            'den': [float(v) for v in den], 'dead_time': float(dead_time)}


def _description(source: Any) -> Any:
    """A ``LinearController`` from itself or from a controller's parameter values (a mapping
    with ``controller``: the kind, as in a scenario's controller section)."""
    from tank_control.core.analysis.linear import LinearController
    if isinstance(source, LinearController):
        return source
    from tank_control.core import scenario as core_scenario
    setup = core_scenario.controller_setup(dict(source), given=())
    kind = setup.kind
    description = kind.linear(setup.settings) if kind.linear is not None else None
    if description is None:
        raise ValueError(f'controller {kind.name}: no linear description: ' + (
            kind.no_linear or 'the kind gives none (ControllerKind.linear; docs/extending.md)'))
    return description


def discrete_transfer_function(response: fr.FrequencyResponse) -> Any:
    """A discrete ``FrequencyResponse`` (``rational(z)·z^(−d)``) as ``control.TransferFunction``
    with ``dt`` = its sample time, the delay as ``d`` poles at z = 0 (exact); ValueError with
    the reason for a continuous one or one given by its values only."""
    control = _control()
    if not response.discrete:
        raise ValueError('response: continuous; use to_transfer_function (Padé) or '
                         'to_frequency_data (exact delay)')
    if response.coefficients is None:
        raise ValueError('response: given by its values only (no coefficients); convert it '
                         'with to_frequency_data')
    num, den = (np.asarray(p, dtype=float) for p in response.coefficients)
    delay = int(round(response.dead_time / response.sample_time))
    den = np.polymul(den, [1.0] + [0.0] * delay)                 # z^(−d): d poles at z = 0
    return control.tf(num, den, response.sample_time)


def controller_transfer_function(source: Any, path: str = 'feedback') -> Any:
    """A controller kind's linear description as a discrete ``control.TransferFunction``
    (``dt`` = its sample time [s]): ``source`` a ``LinearController`` or the controller's
    parameter values (``{'controller': 'pid', 'kp': ..., ...}``); ``path`` ``feedback``
    (``C = −U/Y``, for a plant of positive gain, as the loop analysis closes ``L = C·G``) or
    ``setpoint`` (``U/R``). ValueError with the reason when there is none (e.g. MPCS)."""
    if path not in ('feedback', 'setpoint'):
        raise ValueError(f'path: {path!r}; allowed feedback, setpoint')
    description = _description(source)
    response = description.feedback if path == 'feedback' or description.setpoint is None \
        else description.setpoint
    return discrete_transfer_function(response)


def controller_state_space(source: Any, path: str = 'feedback') -> Any:
    """:func:`controller_transfer_function` as a ``control.StateSpace`` (same ``dt``)."""
    control = _control()
    return control.tf2ss(controller_transfer_function(source, path))
