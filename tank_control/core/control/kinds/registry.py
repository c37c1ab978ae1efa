"""The controller kinds by name (a plain table), and what every caller does with a kind:
resolve parameter values, make the controller, step it with accepted changes.

controller_node, the in-process loop (``core/scenario.py``) and the harness all go through
these functions, so a ROS run and an in-process run execute identical objects.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from tank_control.core.control.kinds import lead_lag, mpcs, pid, relay_autotune, smith_pi, two_loop_pi
from tank_control.core.control.kinds.base import ControllerKind, Settings, resolve
from tank_control.core.interfaces import Controller
from tank_control.core.params import by_name, lookup

KINDS: dict[str, ControllerKind] = by_name(
    pid.KIND,
    two_loop_pi.KIND,
    smith_pi.KIND,
    relay_autotune.KIND,
    mpcs.KIND,
    lead_lag.KIND,
)


def get_kind(name: str) -> ControllerKind:
    """The kind ``name``; ``ConfigError`` with the nearest known name if unknown."""
    return lookup(KINDS, name, 'controller kind')


def settings(kind: ControllerKind, values: Mapping[str, Any],
             given: Iterable[str] | None = None) -> Settings:
    """:func:`~tank_control.core.control.kinds.base.resolve` (defaults, checks, derived
    values); ``ConfigError`` with a one-line reason."""
    return resolve(kind, values, given)


def initial_output(settings_: Settings) -> np.ndarray | None:
    """The output the controller takes over with: ``initial_output``, or ``manual_output`` for
    a kind started in ``mode: manual`` (the operator's value wins); None for a kind without a
    warm start."""
    if settings_.has('mode') and settings_.mode.mode == 'manual':
        return np.array([float(settings_.mode.manual_output)])
    if not settings_.has('warm_start'):
        return None
    return np.array(settings_.warm_start.initial_output, dtype=float)


def build(kind: ControllerKind, settings_: Settings) -> Controller:
    """The controller of ``settings_``, with its warm-start output (``core.loop.warm_start``)."""
    controller = kind.build(settings_)
    controller.initial_output = initial_output(settings_)   # type: ignore[attr-defined]
    return controller


def make_controller(kind_name: str, values: Mapping[str, Any]) -> Controller:
    """The controller ``kind_name`` with parameter ``values`` (missing ones take defaults)."""
    kind = get_kind(kind_name)
    return build(kind, resolve(kind, values))


def step_with_changes(kind: ControllerKind, controller: Controller, settings_: Settings,
                      changed: frozenset[str], t: float, y: np.ndarray, r: np.ndarray,
                      d: np.ndarray) -> tuple[Controller, np.ndarray]:
    """The sample at which accepted parameter changes take effect, bumplessly.

    Returns ``(controller to use from now on, output of this sample)``. A kind with an in-place
    ``update`` changes the running object, then steps (the update keeps the output continuous,
    e.g. the PID's integral absorbs a gain change). Any other kind computes this sample with the
    old object, then a new object built from ``settings_`` is ``reset(y, u)`` to that output and
    stepped once on the same sample (which returns ``u`` by the Controller contract and
    initialises it), so the output is exactly continuous and the new settings act from the next
    sample.
    """
    if kind.update is not None and kind.update(controller, settings_, changed) is not False:
        return controller, np.asarray(controller.step(t, y, r, d), dtype=float)
    u = np.asarray(controller.step(t, y, r, d), dtype=float)
    new = build(kind, settings_)
    new.reset(y, u)
    new.step(t, y, r, d)
    return new, u
