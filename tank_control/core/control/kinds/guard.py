"""The robustness guard of the PID-based kinds ([Checks] §2): ``robustness.ms_max`` refuses a change
whose loop on the process model would be unstable or exceed Ms, and :class:`LoopWatch` reports
the running loop's ``robustness.*`` and ``sampling.warning`` values. Re-exported by
:mod:`~tank_control.core.control.kinds.base`."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from tank_control.core.analysis.robustness import (LoopReport, RobustnessMonitor, finite_or,
                                                   loop_report, pid_key)
from tank_control.core.control.kinds.groups import BIG, group
from tank_control.core.params import param
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.tuning.sampling import sampling_advice

if TYPE_CHECKING:
    from tank_control.core.control.kinds.base import Settings


@dataclass(frozen=True)
class Robustness:
    """The guard on the running loop's robustness ([Checks] §2)."""

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
    """[DeadTimeNotes]'s sampling-time advice on the process model (``core/tuning/sampling.py``)."""

    warning: str = param('', "non-empty when sample_time is above [DeadTimeNotes]'s advice for the process "
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
        """``sampling.warning``: [DeadTimeNotes]'s advice for ``sample_time`` [s] on the model (kept until
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


ROBUSTNESS = group('robustness', Robustness)
ROBUSTNESS_RESULTS = group('robustness_results', RobustnessResults)
SAMPLING_RESULTS = group('sampling_results', SamplingResults)
