"""The parameter groups controller kinds share (channels, mode, fail-safe, warm start, tuning)
and :class:`Group`, a parameter dataclass as one kind uses it. Re-exported by
:mod:`~tank_control.core.control.kinds.base`."""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from tank_control.core.params import TIME_TINY, ConfigError, ParamSpec, config_from, param, specs_of
from tank_control.core.tuning.model import KINDS as MODEL_KINDS, ProcessModel
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
                                   'are set by hand (e.g. [Viteckova] Figs. 4-5: MDP gains, b = c = 0)',
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
                      source='[Precup2013] eq. 3.6.7')
    xi: float = param(0.0, 'smith_pi n = 2: damping xi in [0.5, 1]; rule wang: damping of the '
                      'desired closed loop (0 = not given; wang: 0.707)', unit='-',
                      min=0.0, max=1.0, name='tuning.xi', source='[Precup2013] eq. 3.6.9')
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
                             source='[Precup2013] eq. 3.4.7')
    mt_max: float = param(0.0, 'rule ms: bound on the complementary sensitivity peak Mt '
                          '(0 = none)', unit='-', min=0.0, max=5.0, name='tuning.mt_max')
    tau_c: float = param(0.0, 'rules simc, lambda: desired closed-loop time constant (0 = the '
                         "rule's default: simc L, lambda T)", unit='s', min=0.0, max=BIG,
                         tiny=TIME_TINY, name='tuning.tau_c')
    gain_margin: float = param(0.0, 'rules ho, tan: gain margin A_r (0 = 3)', unit='-',
                               min=0.0, max=100.0, name='tuning.gain_margin',
                               source='[Precup2013] eqs. 3.4.17, 3.4.22')
    phase_margin: float = param(0.0, 'rule ho: phase margin (0 = 60)', unit='deg', min=0.0,
                                max=89.0, name='tuning.phase_margin', source='[Precup2013] eq. 3.4.18')

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
