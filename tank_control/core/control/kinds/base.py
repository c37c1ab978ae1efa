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

from tank_control.core.analysis.robustness import (LoopReport, RobustnessMonitor, finite_or,
                                                   loop_report, pid_key)
from tank_control.core.interfaces import Controller
from tank_control.core.params import (TIME_TINY, ConfigError, ParamSpec, coerce, config_from,
                                      names_of, param, specs_of, unknown_reason)
from tank_control.core.tuning.model import KINDS as MODEL_KINDS, ProcessModel
from tank_control.core.tuning.rules import RULES, tune
from tank_control.core.tuning.sampling import sampling_advice

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
                             min=0.0, max=BIG, tiny=TIME_TINY, name='tuning.dead_time')
    time_constant: float = param(0.0, 'process time constant T (0 = not given)', unit='s',
                                 min=0.0, max=BIG, tiny=TIME_TINY, name='tuning.time_constant')
    ku: float = param(0.0, 'ultimate gain Ku (0 = not given)', unit='u units per y unit',
                      min=0.0, max=BIG, name='tuning.ku')
    tu: float = param(0.0, 'ultimate period Tu (0 = not given)', unit='s', min=0.0, max=BIG,
                      tiny=TIME_TINY, name='tuning.tu')
    te: float = param(0.0, 'smith_pi n = 1: desired closed-loop time constant Te, (0.2...1)*T '
                      '(0 = not given)', unit='s', min=0.0, max=BIG, tiny=TIME_TINY,
                      name='tuning.te',
                      source='004 eq. 3.6.7')
    xi: float = param(0.0, 'smith_pi n = 2: damping xi in [0.5, 1]; rule wang: damping of the '
                      'desired closed loop (0 = not given; wang: 0.707)', unit='-',
                      min=0.0, max=1.0, name='tuning.xi', source='004 eq. 3.6.9')
    order: int = param(1, 'smith_pi model order n (1 or 2)', min=1, max=2, name='tuning.order')
    model: str = param('auto', 'process model: fopdt K/(T*s+1)*e^(-L*s), ipdt k1/s*e^(-L*s), '
                       'sopdt K/((T*s+1)(T2*s+1))*e^(-L*s); auto = sopdt with '
                       'tuning.time_constant2, fopdt with tuning.time_constant, else ipdt. Also '
                       'the model of the robustness.* analysis', name='tuning.model',
                       choices=('auto', *MODEL_KINDS))
    time_constant2: float = param(0.0, 'second time constant T2 of an SOPDT model (0 = not '
                                  'given)', unit='s', min=0.0, max=BIG, tiny=TIME_TINY,
                                  name='tuning.time_constant2')
    ms_target: float = param(1.4, 'rule ms: the sensitivity peak Ms the design may reach',
                             unit='-', min=1.05, max=5.0, name='tuning.ms_target',
                             source='004 eq. 3.4.7')
    mt_max: float = param(0.0, 'rule ms: bound on the complementary sensitivity peak Mt '
                          '(0 = none)', unit='-', min=0.0, max=5.0, name='tuning.mt_max')
    tau_c: float = param(0.0, 'rules simc, lambda: desired closed-loop time constant (0 = the '
                         "rule's default: simc L, lambda T)", unit='s', min=0.0, max=BIG,
                         tiny=TIME_TINY, name='tuning.tau_c')
    gain_margin: float = param(0.0, 'rules ho, tan: gain margin A_r (0 = 3)', unit='-',
                               min=0.0, max=100.0, name='tuning.gain_margin',
                               source='004 eqs. 3.4.17, 3.4.22')
    phase_margin: float = param(0.0, 'rule ho: phase margin (0 = 60)', unit='deg', min=0.0,
                                max=89.0, name='tuning.phase_margin', source='004 eq. 3.4.18')

    def process_model(self) -> ProcessModel | None:
        """The model these parameters describe (gain and dead time given, and the time
        constants the model needs), or None."""
        kind = self.model
        if kind == 'auto':
            kind = ('sopdt' if self.time_constant2 > 0 else
                    'fopdt' if self.time_constant > 0 else 'ipdt')
        t1, t2 = self.time_constant, self.time_constant2
        model = ProcessModel(kind, self.gain, self.dead_time, max(t1, t2), min(t1, t2))
        if self.gain <= 0 or model.reason() is not None:
            return None
        if kind == 'ipdt' and self.dead_time <= 0:
            return None
        return model

    def gains(self, loop: Mapping[str, Any] | None = None, **model: float
              ) -> dict[str, float] | None:
        """The rule's kp, ti, td, b, c in parameter convention (ti = 0: none; a negative kp as
        its magnitude, the sign is direct_action's), None without a rule; ``model`` replaces the
        process arguments (the Smith predictor's own model); ``loop``: the PID's
        ``sample_time`` and ``n``, so model-based rules predict (and ``ms`` designs) the
        implemented discrete loop. ``ConfigError`` names what is missing."""
        if self.rule == 'none':
            return None
        process: dict[str, Any] = {name: getattr(self, name) for name in
                                   ('gain', 'dead_time', 'time_constant', 'time_constant2',
                                    'ku', 'tu', 'te', 'xi', 'tau_c', 'gain_margin',
                                    'phase_margin')}
        process.update(model)
        process = {k: float(v) for k, v in process.items() if v}
        if self.model != 'auto':
            process['model'] = self.model
        if self.rule == 'smith_pi':
            process['n'] = self.order
        if self.rule == 'ms':
            process['ms'] = self.ms_target
            if self.mt_max:
                process['mt'] = self.mt_max
        if loop is not None:
            process['sample_time'] = float(loop['sample_time'])
            process['filter_n'] = float(loop['n'])
        try:
            g = tune(self.rule, self.kind, **process)
        except ValueError as exc:
            text = str(exc).removeprefix('tune: ').replace("process argument '",
                                                           "parameter 'tuning.")
            for plain, name in (("'ms'", "'tuning.ms_target'"), ("'mt'", "'tuning.mt_max'"),
                                ('ms = ', 'tuning.ms_target = ')):
                text = text.replace(plain, name)
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
class Robustness:
    """The guard on the running loop's robustness (SPEC §3)."""

    ms_max: float = param(0.0, 'refuse a gain change (or a tuned design) that would make the '
                          'sensitivity peak Ms of the implemented loop on the process model '
                          'exceed this, or the loop unstable; 0 = off', unit='-', min=0.0,
                          max=10.0, name='robustness.ms_max')

    def reason(self) -> str | None:
        if 0.0 < self.ms_max <= 1.0:
            return (f'robustness.ms_max: {self.ms_max:g} is out of range; Ms >= 1 always, '
                    'allowed 0 (off) or (1, 10]')
        return None


def _rr(default: Any, description: str, name: str, **meta: Any) -> Any:
    return param(default, description, name='robustness.' + name, read_only=True, **meta)


@dataclass(frozen=True)
class RobustnessResults:
    """Robustness of the running loop on the process model, recomputed when the gains or the
    model change (read-only; ``core/analysis/robustness.py``). 0 / none without a model."""

    model: str = _rr('none', 'process model of the analysis (the tuning.* model, the '
                     "auto-tuner's identified one or the Smith predictor's smith.* model); none = "
                     'no analysis', 'model')
    stable: bool = _rr(False, 'closed loop stable (Nyquist count with the exact dead time)',
                       'stable')
    gain_margin: float = _rr(0.0, 'gain margin (0 = infinite: the phase never reaches -180 deg)',
                             'gain_margin', unit='-', min=0.0, max=BIG)
    phase_margin: float = _rr(0.0, 'phase margin', 'phase_margin', unit='deg', min=-BIG,
                              max=BIG)
    ms: float = _rr(0.0, 'sensitivity peak Ms = max|1/(1 + L)|', 'ms', unit='-', min=0.0,
                    max=BIG)
    mt: float = _rr(0.0, 'complementary sensitivity peak Mt = max|L/(1 + L)|', 'mt', unit='-',
                    min=0.0, max=BIG)
    delay_margin: float = _rr(0.0, 'extra dead time that destabilises the loop', 'delay_margin',
                              unit='s', min=0.0, max=BIG)
    crossover: float = _rr(0.0, 'gain crossover frequency', 'crossover', unit='rad/s', min=0.0,
                           max=BIG)
    warning: str = _rr('', 'non-empty when the running loop is unstable on the model or its Ms '
                       'exceeds robustness.ms_max (e.g. after the model changed)', 'warning')


@dataclass(frozen=True)
class SamplingResults:
    """001's sampling-time advice on the process model (``core/tuning/sampling.py``)."""

    warning: str = param('', "non-empty when sample_time is above 001's advice for the process "
                         'model of the analysis (T ≈ 0.3·L, Oppelt; T ≈ (0.1…0.3)·Tu, '
                         'Ziegler–Nichols)', name='sampling.warning', read_only=True)


ROBUSTNESS_NAMES = ('kp', 'ti', 'td', 'n', 'sample_time', 'direct_action', 'robustness.ms_max')
"""Parameters whose change the guard checks (the loop's gains, and the bound itself)."""


def robustness_values(report: LoopReport | None, ms_max: float) -> dict[str, Any]:
    """``robustness.*`` parameter values of a report (none: the defaults)."""
    if report is None:
        return {'robustness.model': 'none', 'robustness.stable': False,
                'robustness.gain_margin': 0.0, 'robustness.phase_margin': 0.0,
                'robustness.ms': 0.0, 'robustness.mt': 0.0, 'robustness.delay_margin': 0.0,
                'robustness.crossover': 0.0, 'robustness.warning': ''}
    warning = ''
    if not report.stable:
        warning = f'the loop is unstable on the model {report.model}'
    elif ms_max > 0 and report.ms > ms_max:
        warning = (f'Ms {report.ms:.3g} > robustness.ms_max {ms_max:g} on the model '
                   f'{report.model}')
    return {'robustness.model': report.model, 'robustness.stable': report.stable,
            'robustness.gain_margin': finite_or(report.gain_margin),
            'robustness.phase_margin': finite_or(report.phase_margin),
            'robustness.ms': finite_or(report.ms), 'robustness.mt': finite_or(report.mt),
            'robustness.delay_margin': finite_or(report.delay_margin),
            'robustness.crossover': finite_or(report.wc), 'robustness.warning': warning}


class LoopWatch:
    """The robustness analysis of a controller's running loop: the process ``model`` (None:
    none known) and ``ms_max``; :meth:`values` gives the ``robustness.*`` values for the
    running configuration, recomputed only when the gains or the model change.
    ``analyse(model, config)`` and ``key(config)``: the controller's analysis (default the
    PID's, a ``PidConfig``)."""

    def __init__(self, model: ProcessModel | None = None, ms_max: float = 0.0,
                 analyse: Callable[[ProcessModel, Any], LoopReport] = loop_report,
                 key: Callable[[Any], Any] = pid_key) -> None:
        self.model = model
        self.ms_max = ms_max
        self._monitor = RobustnessMonitor(analyse, key)
        self._sampling_key: Any = None
        self._sampling = ''

    def report(self, config: Any) -> LoopReport | None:
        return self._monitor.report(self.model, config)

    def values(self, config: Any) -> dict[str, Any]:
        return robustness_values(self.report(config), self.ms_max)

    def sampling(self, sample_time: float) -> dict[str, Any]:
        """``sampling.warning``: 001's advice for ``sample_time`` [s] on the model (kept until
        the model or the sample time changes)."""
        key = (self.model, sample_time)
        if key != self._sampling_key:
            self._sampling_key = key
            self._sampling = sampling_advice(sample_time, self.model)
        return {'sampling.warning': self._sampling}


def pid_gains(pid: Any) -> str:
    """The gains a guard's reason shows for a ``PidConfig``."""
    return f'kp {abs(pid.kp):.4g}, ti {pid.ti:.4g} s, td {pid.td:.4g} s'


def guard_reason(settings: Settings, model: ProcessModel | None, config: Any,
                 analyse: Callable[[ProcessModel, Any], LoopReport] = loop_report,
                 names: tuple[str, ...] = ROBUSTNESS_NAMES,
                 gains: Callable[[Any], str] = pid_gains) -> str | None:
    """The robustness guard: with ``robustness.ms_max`` > 0 and a known ``model``, a change of
    the loop (``names``, default the PID's :data:`ROBUSTNESS_NAMES`, or the tuning rule's
    settings) whose implemented loop ``analyse(model, config)`` (default the PID's) would be
    unstable or exceed Ms is refused, with the numbers. A change of the model alone is not
    refused (it is reported by ``robustness.warning``)."""
    ms_max = settings.robustness.ms_max
    if ms_max <= 0 or model is None:
        return None
    changed = sorted(n for n in settings.given
                     if n in names or (n.startswith('tuning.')
                                       and settings.values.get('tuning.rule') != 'none'))
    if not changed:
        return None
    report = analyse(model, config)
    shown = gains(config)
    loop_names = [n for n in names if n not in ('sample_time', 'robustness.ms_max')]
    what = ', '.join(n for n in loop_names if n in changed) or (
        'tuning.rule' if any(n.startswith('tuning.') for n in changed) else changed[0])
    if not report.stable:
        return (f'{what}: the loop would be unstable ({shown}) on the model {report.model}; '
                f'robustness.ms_max {ms_max:g} refuses it')
    if report.ms > ms_max:
        return (f'{what}: Ms would be {report.ms:.3g} > robustness.ms_max {ms_max:g} '
                f'({shown}; GM {report.gain_margin:.3g}, PM {report.phase_margin:.1f} deg on '
                f'the model {report.model})')
    return None


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
ROBUSTNESS = group('robustness', Robustness)
ROBUSTNESS_RESULTS = group('robustness_results', RobustnessResults)
SAMPLING_RESULTS = group('sampling_results', SamplingResults)


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
      disturbance channels the controller reads (feed-forward).
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
    disturbances: tuple[str, ...] = ()
    summary: Callable[[Values], str] | None = None

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
