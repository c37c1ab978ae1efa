"""controller_node's loop monitoring (docs/monitoring.md): one core ``LoopMonitor`` per loop
(``core/monitoring``), fed at every sample — good or held on a fault — with the plant time [s],
y, r and the output u; each recomputed summary is published as JSON (``std_msgs/String``) on
``~/loop_performance``, and the verdicts join the node's /diagnostics (WARN when a loop needs
attention). Settings ``monitor.*``, declared with the controller's parameters; a change of them
takes effect at the node's next start. A loop's dead time (``monitor.dead_time`` 0) is asked of
the controller's current parameters at each assessment (``core/monitoring/dead_time.py``: its
process model, e.g. one a relay test identified); its source is in the summary and in
/diagnostics (``monitor.dead_time_source.<output>``)."""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from std_msgs.msg import String

from tank_control.core.interfaces import seconds
from tank_control.core.monitoring import diagnostics_line, loop_monitors
from tank_control.core.monitoring.dead_time import DeadTime, controller_dead_times, given_or
from tank_control.core.monitoring.modes import ModeLog
from tank_control.core.params import ConfigError
from tank_control.core.scenario import controller_setup
from tank_control.nodes.messages import reliable_qos

TOPIC = '~/loop_performance'
#: the controller's mode changes (core/monitoring/modes.py), one JSON ``[t, manual, fail_safe]``
#: per change: a run's manual and fail-safe times are computed from them
MODE_TOPIC = '~/loop_mode'


def _strict(value: Any) -> Any:
    """JSON without NaN/inf (as null), numpy numbers as Python numbers."""
    if isinstance(value, Mapping):
        return {str(k): _strict(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_strict(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _short(value: Any) -> float | None:
    """3 significant digits (None for a missing or non-finite value)."""
    if value is None or isinstance(value, bool):
        return None
    value = float(value)
    return float(f'{value:.3g}') if math.isfinite(value) else None


def indices_field(summary: Mapping[str, Any]) -> str:
    """``loop_indices.<output>`` of /diagnostics: the indices of a summary as compact JSON
    (at most about 170 characters; the dashboard's faceplate draws them)."""
    osc, stiction = summary.get('oscillation') or {}, summary.get('stiction') or {}
    detected = bool(osc.get('detected'))
    return json.dumps({
        'harris_index': _short(summary.get('harris_index')),
        'dead_time': _short(summary.get('dead_time')),
        'oscillation': detected,
        'period': _short(osc.get('period')) if detected else None,
        'amplitude': _short(osc.get('amplitude')) if detected else None,
        'stiction': bool(stiction.get('detected')),
        'stiction_index': _short(stiction.get('index')),
        'saturation_pct': _short(summary.get('saturation_pct')),
        'manual_pct': _short(summary.get('manual_pct')),
        'fail_safe_pct': _short(summary.get('fail_safe_pct')),
    }, separators=(',', ':'), allow_nan=False)


class LoopPerformance:
    """The monitors of a controller's loops (output ``outputs[i]`` with input ``inputs[i]``)
    and their publisher; none for a controller whose counts of outputs and inputs differ.
    ``values``: the controller's parameter values, or a function giving the current ones (the
    dead time follows a model identified while running)."""

    def __init__(self, node: Any, values: Mapping[str, Any] | Callable[[], Mapping[str, Any]],
                 kind: Any, sample_time: float, outputs: Sequence[str],
                 inputs: Sequence[str]) -> None:
        self._current = values if callable(values) else (lambda: values)
        setup = controller_setup(self._current(), given=())
        limits = kind.input_limits(setup.settings) if kind.input_limits is not None else {}
        self._config = setup.monitor
        self._outputs, self._inputs = tuple(outputs), tuple(inputs)
        self._seen: Mapping[str, Any] | None = None
        self._known: dict[str, DeadTime] = {}
        providers = {y: (lambda y=y: self.dead_times()[y]) for y in self._outputs}
        self.monitors = loop_monitors(setup.monitor, sample_time, outputs, inputs, limits,
                                      providers)
        # reliable, transient local (as the kinds' state topics): a page or echo that starts
        # later gets the last summary, and the dashboard's String readers match it
        self._pub = (node.create_publisher(String, TOPIC, reliable_qos(10, latched=True))
                     if self.monitors else None)
        self.modes = ModeLog()
        self._mode_pub = (node.create_publisher(String, MODE_TOPIC,
                                                reliable_qos(100, latched=True))
                          if self.monitors else None)

    def dead_times(self) -> dict[str, DeadTime]:
        """Each loop's dead time and its source, from the current parameter values."""
        values = self._current()
        if values != self._seen:
            self._seen = dict(values)
            try:
                setup = controller_setup(values, given=())
                known = controller_dead_times(setup.kind, setup.settings, self._outputs)
            except (ConfigError, ValueError, ArithmeticError) as exc:
                known = {y: DeadTime(None, f'dead time not known ({exc})')
                         for y in self._outputs}
            except Exception as exc:  # noqa: BLE001 - a kind's fault never stops the sampling
                known = {y: DeadTime(None, f'dead time not known ({type(exc).__name__}: '
                                           f'{exc})') for y in self._outputs}
            self._known = {y: given_or(self._config, d) for y, d in known.items()}
        return self._known

    def sample(self, t_ns: int, y: np.ndarray, r: np.ndarray, u: np.ndarray | None,
               manual: bool, fault: str) -> None:
        """One sample of every loop (``fault`` non-empty: the output was held or fail-safe)."""
        change = self.modes.add(seconds(t_ns), manual, bool(fault))
        if change is not None and self._mode_pub is not None:
            self._mode_pub.publish(String(data=json.dumps(change)))
        for name, (u_name, monitor) in self.monitors.items():
            i, j = self._outputs.index(name), self._inputs.index(u_name)
            u_j = float(u[j]) if u is not None and len(u) > j else math.nan
            summary = monitor.update(seconds(t_ns), float(y[i]), float(r[i]), u_j,
                                     manual=manual, fail_safe=bool(fault))
            if summary is not None and self._pub is not None:
                self._pub.publish(String(data=json.dumps(
                    _strict({'output': name, 'input': u_name, **summary}), allow_nan=False)))

    def diagnostics(self) -> tuple[bool, str]:
        """(a loop needs attention, one line of each assessed loop's verdict); (False, '')
        before the first assessment, or without monitors."""
        assessed = {y: pair for y, pair in self.monitors.items()
                    if pair[1].summary().get('verdict') != 'no data'}
        if not assessed:                 # nothing to say before the first assessment
            return False, ''
        level, text = diagnostics_line(assessed)
        return level > 0, text

    def fields(self) -> dict[str, str]:
        """/diagnostics values of each assessed loop: ``loop_performance.<output>`` its
        verdict, ``loop_indices.<output>`` its indices (:func:`indices_field`; the dashboard's
        faceplate shows both), ``monitor.dead_time_source.<output>``."""
        out = {}
        for y, (_, monitor) in self.monitors.items():
            summary = monitor.summary()
            if summary.get('verdict') == 'no data':
                continue
            out[f'loop_performance.{y}'] = str(summary.get('verdict'))
            out[f'loop_indices.{y}'] = indices_field(summary)
            dead_time = summary.get('dead_time')
            out[f'monitor.dead_time_source.{y}'] = (
                f'{dead_time:g} s from {summary.get("dead_time_source")}'
                if dead_time is not None else str(summary.get('dead_time_source')))
        return out
