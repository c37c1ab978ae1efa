"""The controller kinds by name (the built-in table plus installed plugins), and what every caller does with a kind:
resolve parameter values, make the controller, step it with accepted changes.

controller_node, the in-process loop (``core/scenario.py``) and the harness all go through
these functions, so a ROS run and an in-process run execute identical objects.
"""
from __future__ import annotations

import copy
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core import kind_plugins
from tank_control.core.control.kinds import (fsa, lead_lag, mpcs, pid, relay_autotune, smith_pi,
                                             two_loop_pi)
from tank_control.core.control.kinds.base import ControllerKind, Settings, attached, resolve
from tank_control.core.interfaces import Controller
from tank_control.core.params import by_name, finder

BUILT_IN: dict[str, ControllerKind] = by_name(
    pid.KIND,
    two_loop_pi.KIND,
    smith_pi.KIND,
    relay_autotune.KIND,
    mpcs.KIND,
    lead_lag.KIND,
    fsa.KIND,
)
"""The kinds shipped in tank_control."""

PLUGINS = kind_plugins.load(kind_plugins.CONTROLLER_GROUP, BUILT_IN, ControllerKind,
                            'controller kind')
KINDS: dict[str, ControllerKind] = PLUGINS.kinds
"""Every controller kind by name: the built-in ones, then those of installed distributions
(entry points of ``tank_control.controller_kinds``, :mod:`tank_control.core.kind_plugins`);
``PLUGINS.origins`` says where each comes from, ``PLUGINS.errors`` what was left out."""


get_kind: Callable[[str], ControllerKind] = finder(KINDS, 'controller kind')


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
    attached(controller).initial_output = initial_output(settings_)
    return controller


def make_controller(kind_name: str, values: Mapping[str, Any]) -> Controller:
    """The controller ``kind_name`` with parameter ``values`` (missing ones take defaults)."""
    kind = get_kind(kind_name)
    return build(kind, resolve(kind, values))


Sample = tuple[float, np.ndarray, np.ndarray, np.ndarray]
"""``(t, y, r, d)`` of one controller sample."""


@dataclass
class PreparedChange:
    """A live change built and checked before it is accepted (:func:`prepare_change`), that
    takes effect at the next sample with :meth:`take_effect`.

    ``candidate`` is the controller that will run: a copy of the running one with the change
    applied (a kind with ``update``, ``in_place``) or a new object built from the settings.
    """

    kind: ControllerKind
    settings: Settings
    changed: frozenset[str]
    candidate: Controller
    in_place: bool
    deferred: bool = False
    """the running controller could not be copied: ``update`` is applied to it at
    :meth:`take_effect` (no trial before acceptance)"""

    def take_effect(self, running: Controller, t: float, y: np.ndarray, r: np.ndarray,
                    d: np.ndarray) -> tuple[Controller, np.ndarray]:
        """:func:`step_with_changes` with the prepared candidate: ``(controller from now on,
        output of this sample)``. An in-place candidate is a copy of ``running`` taken when it
        was prepared: ``running`` must not have been stepped or reset since."""
        if self.deferred:
            assert self.kind.update is not None        # deferred: an in-place update
            if self.kind.update(running, self.settings, self.changed) is not False:
                return running, np.asarray(running.step(t, y, r, d), dtype=float)
            return PreparedChange(self.kind, self.settings, self.changed,
                                  build(self.kind, self.settings), False
                                  ).take_effect(running, t, y, r, d)
        if self.in_place:
            return self.candidate, np.asarray(self.candidate.step(t, y, r, d), dtype=float)
        u = np.asarray(running.step(t, y, r, d), dtype=float)
        new = self.candidate
        new.reset(y, u)
        new.step(t, y, r, d)
        return new, u


def prepare_change(kind: ControllerKind, controller: Controller, settings_: Settings,
                   changed: frozenset[str], trial: Sample | None = None,
                   u_last: np.ndarray | None = None, copy_running: bool = True
                   ) -> PreparedChange:
    """Build the controller a live change makes and check what the parameters derive.

    The candidate is made once (a kind's ``update`` on a copy of the running controller, else
    ``build``); with ``trial`` (the last sample's ``t, y, r, d``) a copy of it is stepped
    twice from the running state (a rebuilt one first ``reset(y, u_last)``), and every output
    must be finite. ``ValueError`` with a one-line reason when the candidate cannot be made or
    computes a non-finite output; nothing running is touched. ``copy_running`` False applies
    an in-place update to ``controller`` itself (no check possible before).
    """
    try:
        in_place = False
        if kind.update is not None:
            target = _copy(controller) if copy_running else controller
            if target is None:     # a controller that cannot be copied: updated when it acts
                return PreparedChange(kind, settings_, changed, controller, True, deferred=True)
            if kind.update(target, settings_, changed) is not False:
                candidate, in_place = target, True
        if not in_place:
            candidate = build(kind, settings_)
    except (ArithmeticError, ValueError) as exc:
        raise ValueError(f'{", ".join(sorted(changed))}: the controller cannot be made with '
                         f'these values ({exc})') from None
    if trial is not None:
        _trial(candidate, in_place, trial, u_last, changed)
    return PreparedChange(kind, settings_, changed, candidate, in_place)


def _copy(controller: Controller) -> Controller | None:
    """A deep copy of ``controller``, or None if some part of it cannot be copied."""
    try:
        return copy.deepcopy(controller)
    except (TypeError, copy.Error):
        return None


def _trial(candidate: Controller, in_place: bool, trial: Sample, u_last: np.ndarray | None,
           changed: frozenset[str]) -> None:
    """Two samples of a copy of ``candidate`` at the ``trial`` inputs; ValueError unless every
    output is finite."""
    t, y, r, d = trial
    probe = copy.deepcopy(candidate)
    try:
        if not in_place:
            if u_last is None or not np.all(np.isfinite(u_last)):
                return
            probe.reset(y, u_last)
        for k in (1, 2):
            u = np.asarray(probe.step(t + k * probe.sample_time, y, r, d), dtype=float)
            if not np.all(np.isfinite(u)):
                raise ValueError(f'a trial sample gives the non-finite output {u.tolist()}')
    except (ArithmeticError, ValueError) as exc:
        raise ValueError(f'{", ".join(sorted(changed))}: refused, the controller cannot compute '
                         f'with these values ({exc})') from None


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
    prepared = prepare_change(kind, controller, settings_, changed, copy_running=False)
    return prepared.take_effect(controller, t, y, r, d)
