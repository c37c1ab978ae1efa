"""What a controller kind is, and how parameter values become its settings.

A kind (:class:`ControllerKind`) is one module in this package exporting ``KIND``: the
controller's configuration dataclass (its own parameters), the shared groups it reuses
(:func:`channels`, :data:`MODE`, :func:`fail_safe`, :func:`warm_start`, :data:`TUNING`, in
``groups.py``; the robustness guard's in ``guard.py``, both re-exported here), and
functions to build the controller, apply live changes, derive values and report results.
:func:`resolve` turns parameter values into typed :class:`Settings` in one way for parameter
files, ``--set`` overrides, node start-up and live changes.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from types import MappingProxyType
from typing import Any, Protocol, cast

import numpy as np

from tank_control.core.analysis.linear import LinearController
from tank_control.core.control.kinds.groups import (BIG, MODE, TUNING, Channels, FailSafe, Group,
                                                    Mode, Tuning, WarmStart, channels, fail_safe,
                                                    group, warm_start)
from tank_control.core.control.kinds.guard import (ROBUSTNESS, ROBUSTNESS_NAMES,
                                                   ROBUSTNESS_RESULTS, SAMPLING_RESULTS,
                                                   LoopWatch, Robustness, RobustnessResults,
                                                   SamplingResults, guard_reason, pid_gains,
                                                   robustness_values)
from tank_control.core.interfaces import Controller
from tank_control.core.params import (ConfigError, ParamSpec, coerce, config_from, names_of,
                                      specs_of, unknown_reason)
from tank_control.core.tuning.model import ProcessModel

__all__ = [  # the groups and the guard, re-exported: kinds use them as base.<name>
    'BIG', 'MODE', 'TUNING', 'Channels', 'FailSafe', 'Group', 'Mode', 'Tuning', 'WarmStart',
    'channels', 'fail_safe', 'group', 'warm_start', 'ROBUSTNESS', 'ROBUSTNESS_NAMES',
    'ROBUSTNESS_RESULTS', 'SAMPLING_RESULTS', 'LoopWatch', 'Robustness', 'RobustnessResults',
    'SamplingResults', 'guard_reason', 'pid_gains', 'robustness_values',
    # defined here
    'Settings', 'Values', 'ControllerKind', 'resolve', 'Attached', 'attached', 'tuned_gains',
    'tuning_model',
    'siso_reason', 'outputs_within_limits', 'scalar_limits', 'set_changed_gains', 'siso_build',
    'siso_update', 'apply_mode',
]


# --------------------------------------------------------------------------- settings
class Settings:
    """The typed settings of one controller: ``config`` (the kind's own dataclass), every group
    by its key (``settings.mode.manual_output``), ``values``: all parameter values, and
    ``given``: the names the user set (a file, ``--set`` or a live change)."""

    def __init__(self, config: Any, groups: Mapping[str, Any], values: Mapping[str, Any],
                 given: Iterable[str] = ()):
        self.config = config
        self._groups = dict(groups)
        self.values = MappingProxyType(dict(values))
        self.given = frozenset(given)

    def __getattr__(self, name: str) -> Any:
        groups = self.__dict__.get('_groups', {})
        if name in groups:
            return groups[name]
        raise AttributeError(name)

    def has(self, key: str) -> bool:
        return key in self._groups


Values = Mapping[str, Any]


@dataclass(frozen=True)
class ControllerKind:
    """Everything controller_node, the in-process loop and the harness need of one controller.

    * ``config``: the controller's configuration dataclass (its fields are its parameters);
      ``groups``: shared parameter groups (channels, mode, fail-safe, warm start, tuning);
    * ``build(settings)`` → the :class:`~tank_control.core.interfaces.Controller`;
    * ``update(controller, settings, changed)``: apply accepted changes in place, bumplessly;
      returning False (or ``update=None``) rebuilds: see :func:`step_with_changes`;
    * ``derive(values)`` → parameter values that follow from others (a tuning rule's gains),
      written back so ``ros2 param get`` shows them; a derived parameter set by the user must
      equal the derived value (one rule for files, ``--set`` and live changes);
    * ``reason(settings)``: relations across groups (one-line reason or None);
    * ``results(controller)``: values the controller produced while running (written back to
      parameters); ``state``: the ``results`` entry that is a state machine's state;
    * ``commands``: operator commands, offered as ``std_srvs/Trigger`` services ``~/<name>``;
    * ``summary(values)``: one line of what the controller found (e.g. an identified model and
      its gains; '' for nothing yet), logged by the node when it changes, printed by the harness;
    * ``gains``: parameters reported as the run's final gains; ``input_limits(settings)``:
      ``{input channel: (min, max)}`` for constraint metrics; ``disturbances``: the measured
      disturbance channels the controller reads (feed-forward);
    * ``linear(settings)`` → the controller's linear description
      (:class:`~tank_control.core.analysis.linear.LinearController`: its discrete transfer
      function, the models it carries) or None; a kind without it (``linear=None``) is not
      analysed (``tank-control analyze``, ``analysis.png``, the dashboard's robustness panel).

    ``update``, ``results`` and ``commands`` take the kind's own controller (what its ``build``
    returns, typed ``Any`` here).
    """

    name: str
    description: str
    config: type
    build: Callable[[Settings], Controller]
    groups: tuple[Group, ...] = ()
    update: Callable[[Any, Settings, frozenset[str]], bool | None] | None = None
    derive: Callable[[Values], Mapping[str, Any]] | None = None
    reason: Callable[[Settings], str | None] | None = None
    results: Callable[[Any], Mapping[str, Any]] | None = None
    state: str | None = None
    commands: Mapping[str, Callable[[Any], tuple[bool, str]]] = field(
        default_factory=dict)
    gains: tuple[str, ...] = ()
    input_limits: Callable[[Settings], Mapping[str, tuple[float, float]]] | None = None
    disturbances: tuple[str, ...] = ()
    summary: Callable[[Values], str] | None = None
    linear: Callable[[Settings], LinearController | None] | None = None
    slow: tuple[str, ...] = ()
    """Parameters whose live change is costly to build (design matrices, a search): in wall
    mode controller_node builds the changed controller in a worker thread, the running one
    keeps sampling, and it switches at the first sample after the result is ready
    (``nodes/live_rebuild.py``)."""
    adopt: Callable[[Any, Any, frozenset[str]], bool] | None = None
    """``adopt(running, candidate, changed)``: take such a candidate (a copy of the running
    controller as it was, changed) into the running controller, as its ``update`` would at
    this sample; False when it cannot (the candidate then takes over by ``reset(y, u)``)."""
    no_linear: str = ''
    """Why a kind without ``linear`` has none (``tank-control analyze`` and the dashboard say
    it)."""
    loop_dead_times: Callable[[Settings], Mapping[str, tuple[float, str]]] | None = None
    """Each loop's dead time in the controller's own model: output channel → (seconds, where
    from), for the loop monitor's Harris index (``core/monitoring/dead_time.py``); None: the
    dead time of the model ``linear`` carries (a SISO kind)."""

    def specs(self) -> tuple[ParamSpec, ...]:
        """The kind's parameters: its configuration's, then each group's."""
        return specs_of(self.config) + tuple(s for g in self.groups for s in g.specs())


def resolve(kind: ControllerKind, values: Values, given: Iterable[str] | None = None) -> Settings:
    """Typed settings from parameter values (missing ones take the kind's defaults).

    Unknown names are refused with the nearest known name; every value is checked against its
    parameter; derived values (``kind.derive``) are applied, and a derived parameter among
    ``given`` (the names a file, ``--set`` or a live change set; default: all of ``values``)
    must equal its derived value. Raises :class:`ConfigError` with a one-line reason.
    """
    specs = {s.name: s for s in kind.specs()}
    complete = {name: s.default for name, s in specs.items()}
    for name, value in values.items():
        spec = specs.get(name)
        if spec is None:
            raise ConfigError(unknown_reason(name, specs))
        value = coerce(spec, value)
        reason = spec.check(value)
        if reason:
            raise ConfigError(reason)
        complete[name] = value
    given = set(values if given is None else given)
    if kind.derive is not None:
        for name, value in kind.derive(complete).items():
            value = coerce(specs[name], value)
            if name in given and not _same(complete[name], value):
                raise ConfigError(_conflict(name, complete[name], value, complete))
            complete[name] = value
    own = names_of(kind.config)
    config = config_from(kind.config, {n: complete[n] for n in own})
    groups = {g.key: g.build({s.name: complete[s.name] for s in g.specs()}) for g in kind.groups}
    settings = Settings(config, groups, complete, given)
    reason = kind.reason(settings) if kind.reason is not None else None
    if reason:
        raise ConfigError(reason)
    return settings


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-15)
    return a == b


def _conflict(name: str, value: Any, derived: Any, values: Values) -> str:
    rule = values.get('tuning.rule', '')
    hint = ('set tuning.setpoint_weights to false to set b and c by hand, or tuning.rule to none'
            if name in ('b', 'c') else 'set tuning.rule to none to tune by hand')
    return (f'{name}: {value:g} conflicts with tuning.rule {rule!r}, which gives {derived:g}; '
            f'{hint}')


class Attached(Protocol):
    """The members a controller carries besides :class:`Controller`'s, set from outside its
    class when a kind builds it (``core.loop.initial_output`` reads ``initial_output``); a
    controller made otherwise may lack them (read with ``getattr(controller, name, None)``).
    Reach them with :func:`attached`."""

    initial_output: np.ndarray | None
    """[input units] the warm start takes over with (``kinds.registry.build``; None: none)"""
    loop_watch: LoopWatch
    """robustness of the running loop (the kinds with ``robustness.*`` results)"""


def attached(controller: object) -> Attached:
    """``controller`` seen with its :class:`Attached` members (no check: the kind that built it
    set the ones it reads)."""
    return cast(Attached, controller)


# ------------------------------------------------------------------- shared functions
def tuned_gains(values: Values) -> dict[str, float]:
    """``derive`` of the PID-based kinds: the gains of ``tuning.*`` (none without a rule),
    model-based rules on the implemented loop (``sample_time``, ``n``)."""
    return TUNING.build({s.name: values[s.name] for s in TUNING.specs()}).gains(values) or {}


def tuning_model(values: Values) -> ProcessModel | None:
    """The process model of the ``tuning.*`` parameters, or None."""
    return TUNING.build({s.name: values[s.name] for s in TUNING.specs()}).process_model()


def siso_reason(settings: Settings, limits: Any = None) -> str | None:
    """Relations of the SISO kinds: one channel each way, manual and fail-safe outputs within
    the output limits ``u_min``/``u_max`` of ``limits`` (default: the kind's config)."""
    limits = settings.config if limits is None else limits
    for name, names in (('output_names', settings.channels.output_names),
                        ('input_names', settings.channels.input_names)):
        if len(names) != 1:
            return f'{name}: {list(names)} must name exactly 1 channel (a SISO controller)'
    return outputs_within_limits(settings, [(limits.u_min, limits.u_max)])


def outputs_within_limits(settings: Settings, limits: list[tuple[float, float]]) -> str | None:
    """``manual_output`` and ``fail_safe_output`` within the output limits (one per input);
    ``initial_output`` has one value per input (it is clipped to the limits)."""
    values = settings.values
    checks = [('fail_safe_output', values.get('fail_safe_output'))]
    if settings.has('mode'):
        checks.append(('manual_output', values['manual_output']))
    for name, value in checks:
        if value is None:
            continue
        items = list(value) if isinstance(value, (list, tuple)) else [value] * len(limits)
        if len(items) != len(limits):
            return f'{name}: {items} must hold {len(limits)} value(s), one per input'
        for item, (lo, hi) in zip(items, limits):
            if not lo <= item <= hi:
                shown = items if len(items) > 1 else item
                return (f'{name}: {shown} is outside the output limits '
                        + ', '.join(f'[{a:g}, {b:g}]' for a, b in limits))
    u0 = list(values.get('initial_output', []))
    inputs = list(settings.channels.input_names)
    if len(u0) != len(inputs):
        return f'initial_output: {u0} must hold {len(inputs)} value(s), one per input {inputs}'
    return None


def forwarded_commands(names: Iterable[str]
                       ) -> dict[str, Callable[[Any], tuple[bool, str]]]:
    """``commands`` of a kind whose controller runs them itself: ``controller.command(name)``."""
    def forward(name: str) -> Callable[[Any], tuple[bool, str]]:
        return lambda controller: controller.command(name)
    return {name: forward(name) for name in names}


def scalar_limits(settings: Settings) -> dict[str, tuple[float, float]]:
    """``input_limits`` of a SISO kind: its config's ``u_min``, ``u_max``."""
    return {settings.channels.input_names[0]: (settings.config.u_min, settings.config.u_max)}


def set_changed_gains(pid: Any, config: Any, names: Iterable[str] | None = None) -> None:
    """``pid.set_gains`` (bumpless) with the fields of ``config`` (a ``PidConfig``) that differ
    from the running ones, among ``names`` (default all)."""
    new = asdict(config)
    running = pid.config
    changes = {k: v for k, v in new.items()
               if (names is None or k in names) and getattr(running, k) != v}
    if changes:
        pid.set_gains(**changes)


def siso_build(controller_class: Callable[..., Any]) -> Callable[[Settings], Any]:
    """``build`` for a kind whose controller is a ``SisoController`` (core/control/siso_law.py)
    made from the kind's configuration: the channels, and manual output when started in
    ``mode: manual``."""
    def build(settings: Settings) -> Any:
        controller = controller_class(settings.config,
                                      output_name=settings.channels.output_names[0],
                                      input_name=settings.channels.input_names[0])
        if settings.mode.mode == 'manual':
            controller.law.set_manual(float(settings.mode.manual_output))
        return controller
    return build


def siso_update(controller: Any, settings: Settings, changed: frozenset[str]) -> bool:
    """``update`` for such a kind: changed settings through the law's ``set_gains`` (the
    integral absorbs the change, so the output stays continuous), then the mode (manual
    output / bumpless return to auto)."""
    law = controller.law
    set_changed_gains(law, settings.config)
    apply_mode(law, law.mode, settings, changed)
    return True


def apply_mode(target: Any, mode_now: str, settings: Settings, changed: frozenset[str]) -> None:
    """Manual output on request (or when the mode changes), bumpless return to auto."""
    mode = settings.mode
    if mode.mode == 'manual' and ({'mode', 'manual_output'} & changed or mode_now != 'manual'):
        target.set_manual(float(mode.manual_output))
    elif mode.mode == 'auto' and mode_now != 'auto':
        target.set_auto()
