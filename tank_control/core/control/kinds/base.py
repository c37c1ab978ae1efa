"""What a controller kind is, the parameter groups kinds share, and how values become settings.

A kind (:class:`ControllerKind`) is one module in this package exporting ``KIND``: the
controller's configuration dataclass (its own parameters), the shared groups it reuses
(:func:`channels`, :data:`MODE`, :func:`fail_safe`, :func:`warm_start`, :data:`TUNING`), and
functions to build the controller, apply live changes, derive values and report results.
:func:`resolve` turns parameter values into typed :class:`Settings` in one way for parameter
files, ``--set`` overrides, node start-up and live changes.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from types import MappingProxyType
from typing import Any

from tank_control.core.interfaces import Controller
from tank_control.core.params import (ConfigError, ParamSpec, coerce, config_from, names_of,
                                      param, specs_of, unknown_reason)
from tank_control.core.tuning.rules import RULES, tune

BIG = 1e12


# ------------------------------------------------------------------------------ groups
@dataclass(frozen=True)
class Channels:
    """The channels a controller reads (measurement and setpoint) and writes."""

    output_names: tuple[str, ...] = param(('y',), 'measured channels read (and their '
                                          'setpoints), by name in the measurement/setpoint '
                                          'messages', read_only=True)
    input_names: tuple[str, ...] = param(('u',), 'manipulated channels written, by name in the '
                                         'manipulated message', read_only=True)


@dataclass(frozen=True)
class Mode:
    """Automatic or manual operation (bumpless both ways)."""

    mode: str = param('auto', 'auto = closed loop; manual = output is manual_output (bumpless '
                      'both ways)', choices=('auto', 'manual'))
    manual_output: float = param(0.0, 'output in manual mode', unit='u units', min=-BIG, max=BIG)


@dataclass(frozen=True)
class FailSafe:
    """What the node sends on a stale or non-finite measurement."""

    fail_safe: str = param('hold', 'on a stale or non-finite measurement: hold the last output '
                           'or send fail_safe_output', choices=('hold', 'output'))
    fail_safe_output: float | tuple[float, ...] = param(
        0.0, "output sent on a measurement fault when fail_safe = 'output', one value per "
        'input channel', unit='u units', min=-BIG, max=BIG)


@dataclass(frozen=True)
class WarmStart:
    """The output a controller takes over with (bumpless take-over of a running plant)."""

    initial_output: tuple[float, ...] = param(
        (0.0,), 'output at the first sample when the measurement equals the setpoint: the '
        'controller is reset(y, initial_output) there, one value per input channel, clipped to '
        'the output limits', unit='u units', min=-BIG, max=BIG, read_only=True)


@dataclass(frozen=True)
class Tuning:
    """A tuning rule that sets the gains from a process model or the ultimate point."""

    rule: str = param('none', 'tuning rule; not none: the gains come from it', name='tuning.rule',
                      choices=('none', *RULES))
    kind: str = param('pid', 'controller type the rule designs', name='tuning.kind',
                      choices=('p', 'pi', 'pd', 'pid'))
    setpoint_weights: bool = param(True, 'true: b and c come from the rule as well; false: b, c '
                                   'are set by hand (e.g. 000 Figs. 4-5: MDP gains, b = c = 0)',
                                   name='tuning.setpoint_weights')
    gain: float = param(0.0, 'process gain K or k1 (0 = not given)',
                        unit='y units per u unit, per s for IPDT', min=0.0, max=BIG,
                        name='tuning.gain')
    dead_time: float = param(0.0, 'process dead time L or To (0 = not given)', unit='s',
                             min=0.0, max=BIG, name='tuning.dead_time')
    time_constant: float = param(0.0, 'process time constant T (0 = not given)', unit='s',
                                 min=0.0, max=BIG, name='tuning.time_constant')
    ku: float = param(0.0, 'ultimate gain Ku (0 = not given)', unit='u units per y unit',
                      min=0.0, max=BIG, name='tuning.ku')
    tu: float = param(0.0, 'ultimate period Tu (0 = not given)', unit='s', min=0.0, max=BIG,
                      name='tuning.tu')
    te: float = param(0.0, 'smith_pi n = 1: desired closed-loop time constant Te, (0.2...1)*T '
                      '(0 = not given)', unit='s', min=0.0, max=BIG, name='tuning.te',
                      source='004 eq. 3.6.7')
    xi: float = param(0.0, 'smith_pi n = 2: damping xi in [0.5, 1] (0 = not given)', unit='-',
                      min=0.0, max=1.0, name='tuning.xi', source='004 eq. 3.6.9')
    order: int = param(1, 'smith_pi model order n (1 or 2)', min=1, max=2, name='tuning.order')

    def gains(self, **model: float) -> dict[str, float] | None:
        """The rule's kp, ti, td, b, c in parameter convention (ti = 0: none; a negative kp as
        its magnitude, the sign is direct_action's), None without a rule; ``model`` replaces the
        process arguments (the Smith predictor's own model). ``ConfigError`` names what is
        missing."""
        if self.rule == 'none':
            return None
        process = {name: getattr(self, name) for name in
                   ('gain', 'dead_time', 'time_constant', 'ku', 'tu', 'te', 'xi')}
        process.update(model)
        process = {k: float(v) for k, v in process.items() if v}
        if self.rule == 'smith_pi':
            process['n'] = self.order
        try:
            g = tune(self.rule, self.kind, **process)
        except ValueError as exc:
            text = str(exc).removeprefix('tune: ').replace("process argument '",
                                                           "parameter 'tuning.")
            raise ConfigError(f'tuning.rule {self.rule!r} with tuning.kind {self.kind!r}: '
                              f'{text}') from None
        out = {'kp': abs(float(g['kp'])),
               'ti': float(g['ti']) if g.get('ti') is not None else 0.0,
               'td': float(g['td']) if g.get('td') is not None else 0.0}
        if self.setpoint_weights:
            out['b'] = float(g['b']) if g.get('b') is not None else 1.0
            out['c'] = float(g['c']) if g.get('c') is not None else 1.0
        return out


@dataclass(frozen=True)
class Group:
    """A parameter dataclass a kind uses, with the kind's own defaults (by field name) and,
    optionally, only some of its fields (``only``)."""

    key: str
    config: type
    defaults: Mapping[str, Any] = field(default_factory=dict)
    only: tuple[str, ...] | None = None

    def specs(self) -> tuple[ParamSpec, ...]:
        specs = specs_of(self.config, **self.defaults)
        return specs if self.only is None else tuple(s for s in specs if s.name in self.only)

    def build(self, values: Mapping[str, Any]) -> Any:
        return config_from(self.config, values, **self.defaults)


def group(key: str, config: type, only: Iterable[str] | None = None, **defaults: Any) -> Group:
    """A :class:`Group` (``defaults`` by field name)."""
    return Group(key, config, MappingProxyType(dict(defaults)),
                 tuple(only) if only is not None else None)


def channels(outputs: tuple[str, ...], inputs: tuple[str, ...]) -> Group:
    return group('channels', Channels, output_names=outputs, input_names=inputs)


def fail_safe(output: float | tuple[float, ...] = 0.0) -> Group:
    return group('fail_safe', FailSafe, fail_safe_output=output)


def warm_start(output: tuple[float, ...] = (0.0,)) -> Group:
    return group('warm_start', WarmStart, initial_output=output)


MODE = group('mode', Mode)
TUNING = group('tuning', Tuning)


# --------------------------------------------------------------------------- settings
class Settings:
    """The typed settings of one controller: ``config`` (the kind's own dataclass), every group
    by its key (``settings.mode.manual_output``), and ``values``: all parameter values."""

    def __init__(self, config: Any, groups: Mapping[str, Any], values: Mapping[str, Any]):
        self.config = config
        self._groups = dict(groups)
        self.values = MappingProxyType(dict(values))

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
    * ``gains``: parameters reported as the run's final gains; ``input_limits(settings)``:
      ``{input channel: (min, max)}`` for constraint metrics.
    """

    name: str
    description: str
    config: type
    build: Callable[[Settings], Controller]
    groups: tuple[Group, ...] = ()
    update: Callable[[Controller, Settings, frozenset[str]], bool | None] | None = None
    derive: Callable[[Values], Mapping[str, Any]] | None = None
    reason: Callable[[Settings], str | None] | None = None
    results: Callable[[Controller], Mapping[str, Any]] | None = None
    state: str | None = None
    commands: Mapping[str, Callable[[Controller], tuple[bool, str]]] = field(
        default_factory=dict)
    gains: tuple[str, ...] = ()
    input_limits: Callable[[Settings], Mapping[str, tuple[float, float]]] | None = None

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
    settings = Settings(config, groups, complete)
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


# ------------------------------------------------------------------- shared functions
def tuned_gains(values: Values) -> dict[str, float]:
    """``derive`` of the PID-based kinds: the gains of ``tuning.*`` (none without a rule)."""
    return TUNING.build({s.name: values[s.name] for s in TUNING.specs()}).gains() or {}


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
