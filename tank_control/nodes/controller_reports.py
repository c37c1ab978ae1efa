"""The controller node's reports: /diagnostics, its results as parameters, its state topic,
its commands, the fail-safe output of a fault episode and the saturation watch (docs/nodes.md, "controller_node")."""
from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import String
from std_srvs.srv import Trigger

from tank_control.core.control.kinds.base import ControllerKind
from tank_control.nodes.loop_performance import LoopPerformance
from tank_control.nodes.controller_inputs import ControllerInputs
from tank_control.nodes.params import ParameterBinding
from tank_control.nodes.runtime import NAME_CHECK_PERIOD, duplicate_name_problem

#: a second controller of this name seen this long after a failed auto-tune test is named as
#: its likely cause (its data can come before its name; the name watch looks every 2 s) [s]
LATE_CAUSE_S = 3 * NAME_CHECK_PERIOD + 4.0

#: consecutive samples with an input at its limit after which /diagnostics says WARN
SATURATION_WARN_SAMPLES = 20


class ControllerReports(ControllerInputs):
    """What ``controller_node`` reports (a base class of ``ControllerNode``)."""

    _kind: ControllerKind
    _controller: Any
    _params: ParameterBinding
    _inputs: tuple[str, ...]
    _u: np.ndarray | None
    _gen: int
    _started: bool
    _causes: dict[str, str]
    _failed_at: float | None = None     # time.monotonic() of the last auto-tune failure [s]
    _saturated_samples: int
    _state_pub: Any
    _diag_pub: Any
    _pub: Any
    _reference_subs: list[Any]
    _matched_sent: dict[str, int] | None
    _prestart_calls: int
    _prestart_timer: Any
    _warning: str
    _fault: str
    _fault_reason: str
    _update_error: str
    _clock_conflict: str
    _performance: LoopPerformance
    _waiting_logged: str = ''         # the 'waiting for ...' last said on the console
    _compute_s: float

    def _check_saturation(self) -> None:
        """Count consecutive samples with an input at its limit (the controller's
        ``saturated``); from ``SATURATION_WARN_SAMPLES`` on, /diagnostics is WARN naming the
        inputs (a setpoint the inputs cannot reach), logged once per episode."""
        status = self._controller.status
        if not status.get('saturated', False):
            if self._saturated_samples >= SATURATION_WARN_SAMPLES:
                self._saturated_samples = 0
                self._publish_diagnostics()
            self._saturated_samples = 0
            return
        self._saturated_samples += 1
        if self._saturated_samples == SATURATION_WARN_SAMPLES:
            self.get_logger().warning(f'{self._saturation_text(status)}: the setpoint may be '
                                      'out of reach')
            self._publish_diagnostics()

    def _saturation_text(self, status: Mapping[str, Any]) -> str:
        names = [n for n in self._inputs if status.get(f'saturated.{n}', False)]
        which = ', '.join(names) if names else ', '.join(self._inputs)
        return f'input(s) {which} at their limits for {self._saturated_samples} samples'

    def _name_late_cause(self, problem: str) -> None:
        """The name watch saw a second controller of this name only after a test had failed
        (its messages came before its name reached this node's graph): a failure at most
        :data:`LATE_CAUSE_S` before names it as the likely cause, as one seen in time does."""
        state = self._kind.state
        if (not state or '.' not in state or self._failed_at is None
                or time.monotonic() - self._failed_at > LATE_CAUSE_S):
            return
        reason = self._params.values.get(state.rsplit('.', 1)[0] + '.reason')
        if self._params.values.get(state) == 'failed' and reason and reason not in (
                self._causes.values()):
            self._causes = {str(reason): f'{reason} (likely cause: {problem})'}
            self._write_results()

    def _write_results(self, cause: str = '') -> None:
        """Values the controller produced (kind.results) → parameters, when they changed
        (``cause``: the command that produced them, named on /parameter_audit)."""
        if self._kind.results is None:
            return
        current = self._params.values
        results = dict(self._kind.results(self._controller))
        state = self._kind.state
        reason_key = state.rsplit('.', 1)[0] + '.reason' if state and '.' in state else ''
        if results.get(reason_key) in self._causes:
            results[reason_key] = self._causes[results[reason_key]]
        changed = {k: v for k, v in results.items() if current.get(k) != v}
        if state is not None and changed.get(state) == 'failed' and changed.get(reason_key):
            # A test that failed beside a second controller of this name (another graph
            # joined before the name watch saw it): the failure names it as the likely cause.
            self._failed_at = time.monotonic()
            problem = duplicate_name_problem(self)
            if problem:
                reason = changed[reason_key]
                self._causes = {reason: f'{reason} (likely cause: {problem})'}
                changed[reason_key] = self._causes[reason]
        if changed:
            result = self._params.write(changed, source=f'controller {self._kind.name}{cause}')
            if not result.successful:
                self._log_once(f'controller results not written to parameters: {result.reason}')
            published = False
            if state is not None and state in changed and self._state_pub is not None:
                self._state_pub.publish(String(data=str(changed[state])))
                self.get_logger().info(f'{self._state_text()}')
                self._publish_diagnostics()
                published = True
            self._log_summary()
            warnings = [f'{k}: {v}' for k, v in changed.items() if k.endswith('.warning') and v]
            for text in warnings:
                self.get_logger().warning(text)
            if (warnings or any(k.endswith('.warning') for k in changed)) and not published:
                self._publish_diagnostics()

    def _log_summary(self) -> None:
        """Log the kind's summary of what it found (the auto-tuner: Ku, Tu, model, gains) once
        per new result."""
        summary = self._kind.summary(self._params.values) if self._kind.summary else ''
        if summary and summary != getattr(self, '_summary_logged', ''):
            self.get_logger().info(f'found: {summary}')
        self._summary_logged = summary

    def _state_text(self) -> str:
        """``<state name> <state>[: reason]`` of a kind with a state machine, else ''."""
        state = self._kind.state
        if state is None:
            return ''
        values = self._params.values
        reason = values.get(state.rsplit('.', 1)[0] + '.reason', '') if '.' in state else ''
        return f'{state} {values[state]}' + (f': {reason}' if reason else '')

    def _on_command(self, command: str, request: Trigger.Request,
                    response: Trigger.Response) -> Trigger.Response:
        """An operator command (std_srvs/Trigger ``~/<command>``) for the running controller."""
        self._gen += 1               # the command may change the running controller
        try:
            response.success, response.message = self._kind.commands[command](self._controller)
        except ValueError as exc:
            response.success, response.message = False, f'{command}: {exc}'
        self.get_logger().info(f'{command}: {response.message}')
        self._write_results(f', command {self.get_fully_qualified_name()}/{command}')
        return response

    _FAULT_COUNTERS = {'stale': 'stale_samples', 'non-finite': 'nonfinite_measurements',
                       'out-of-range': 'out_of_range_measurements',
                       'controller': 'controller_faults'}

    def _hold(self, fault: str) -> np.ndarray:
        """The output on a fault: the last output (``fail_safe: hold``) or ``fail_safe_output``
        (``output``, or no output yet); a new episode is logged once and reported."""
        self.counters[self._FAULT_COUNTERS[fault]] += 1
        values = self._params.values
        fail_safe = values.get('fail_safe', 'hold') == 'output' or self._u is None
        if fail_safe or self._u is None:
            u = np.broadcast_to(np.asarray(values.get('fail_safe_output', 0.0), dtype=float),
                                (len(self._inputs),)).copy()
        else:
            u = self._u.copy()
        if self._fault != fault:
            self.counters['fault_episodes'] += 1
            action = 'fail_safe_output' if fail_safe else 'last output held'
            if fault == 'controller':
                self.get_logger().error(f'controller fault ({self._fault_reason}): {action} '
                                        f'{u.tolist()} until it computes again')
            else:
                self.get_logger().warning(f'measurement {fault}: {action} {u.tolist()} until '
                                          'good measurements return')
            self._fault = fault
            self._u = u
            self._publish_diagnostics()
        self._u = u
        return u

    # ----------------------------------------------------------- diagnostics
    def _check_warning(self) -> None:
        """The controller's configuration warning (its ``warning`` attribute, '' for none;
        e.g. MPCS horizons shorter than its dead times): logged when it appears or
        changes, and shown in ``/diagnostics`` (level WARN, in the message) while it lasts."""
        warning = str(getattr(self._controller, 'warning', '') or '')
        if warning == self._warning:
            return
        self._warning = warning
        if warning:
            self.get_logger().warning(warning)
        self._publish_diagnostics()

    def _matched(self) -> dict[str, int]:
        """``matched_writers.<topic>``: writers the middleware has matched to this node's
        readers of the reference's signals; ``matched_readers.<topic>``: readers matched to its
        writer of ``manipulated``. In /diagnostics: the harness starts the clock (sim/wall), and
        resumes it after restarting this node (lockstep), once they reach what its own graph
        shows (the plant reports its own topics): a writer's first answers reach only the
        readers it has matched."""
        items = {f'matched_writers.{sub.topic_name}': sub.get_publisher_count()
                 for sub in self._reference_subs}
        items[f'matched_readers.{self._pub.topic_name}'] = self._pub.get_subscription_count()
        return items

    def _on_prestart(self) -> None:
        """Before the first sample (every 20 ms): /diagnostics at once when a matched count
        changed, else every 0.1 s."""
        if self._started:
            self._prestart_timer.cancel()      # (cancelled, not destroyed, in its own callback)
            return
        self._prestart_calls += 1
        if self._matched() != self._matched_sent or self._prestart_calls % 5 == 0:
            self._publish_diagnostics()

    def _say_what_it_waits_for(self, message: str) -> None:
        """On the console too: once when the controller starts waiting (no plant yet), once
        when it stops."""
        waiting = message if message.startswith('waiting for') else ''
        if waiting and waiting != self._waiting_logged:
            self.get_logger().info(f'{waiting} (from plant_node): nothing to control yet')
        elif not waiting and self._waiting_logged:
            self.get_logger().info('measurements arrive: the loop runs')
        self._waiting_logged = waiting

    def _publish_diagnostics(self) -> None:
        self._limited.clear()                 # input reasons are logged again (rate limit)
        self._future.rearm_reports()
        status = dict(self._controller.status)
        level = (DiagnosticStatus.WARN if self._fault or self._warning
                 else DiagnosticStatus.OK)
        waiting = self._protocol.waiting_for_measurement()
        message = (f'controller fault: {self._fault_reason}; holding' if self._fault == 'controller'
                   else f'measurement {self._fault}: holding' if self._fault
                   else 'waiting for measurement' if waiting
                   else "waiting for the plant's time_origin" if self._protocol.origin_ns is None
                   else 'running')
        self._say_what_it_waits_for(message)
        if self._kind.state is not None:
            message += f'; {self._state_text()}'
        results = dict(self._kind.results(self._controller)) if self._kind.results else {}
        warnings = [f'{k}: {v}' for k, v in results.items() if k.endswith('.warning') and v]
        if warnings:
            level = DiagnosticStatus.WARN
            message += '; ' + '; '.join(warnings)
        if self._warning:
            message += f'; warning: {self._warning}'
        if self._update_error:
            message += f'; {self._update_error}'
        if self.counters['rejected_future']:
            level = max(level, DiagnosticStatus.WARN)
            message += (f"; {self.counters['rejected_future']} inputs stamped in the future "
                        'refused')
        if self.counters['rejected_past']:
            level = max(level, DiagnosticStatus.WARN)
            message += (f"; {self.counters['rejected_past']} setpoint/disturbance messages "
                        'stamped in the past refused')
        attention, performance = self._performance.diagnostics()
        if performance:
            message += f'; {performance}'
            if attention:
                level = max(level, DiagnosticStatus.WARN)
        if self._fault == 'controller' or self._update_error:
            level = DiagnosticStatus.ERROR
        if self._clock_conflict:
            level = DiagnosticStatus.ERROR
            message = f'not sampling: {self._clock_conflict}'
        if self._saturated_samples >= SATURATION_WARN_SAMPLES:
            level = DiagnosticStatus.ERROR if self._clock_conflict else DiagnosticStatus.WARN
            message += f'; {self._saturation_text(status)}'
        fields = {
            'controller': self._params.values['controller'],
            'clock_mode': self._protocol.mode,
            'trigger': self._protocol.trigger,
            'mode': status.get('mode', 'auto'),
            'saturated': status.get('saturated', False),
            'saturated_samples': self._saturated_samples,
            'anti_windup_active': status.get('anti_windup_active', False),
            'fault': self._fault or 'none',
            'stale_inputs': self._fault == 'stale',
            'rejected_parameters': self._params.rejected,
            'last_computation_time_us': round(self._compute_s * 1e6, 3),
            'output': [] if self._u is None else self._u.tolist(),
            **self.counters,
            **{f'status.{k}': v for k, v in status.items()
               if isinstance(v, (bool, int, float, str))},
            **{k: v for k, v in results.items()
               if k.startswith(('robustness.', 'autotune.')) and k != 'autotune.start'},
            **self._performance.fields(),
        }
        self._matched_sent = self._matched()
        fields.update(self._matched_sent)
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [DiagnosticStatus(
            level=level, name=f'{self.get_name()}: {fields["controller"]}', message=message,
            hardware_id='tank_control',
            values=[KeyValue(key=k, value=str(v)) for k, v in fields.items()])]
        self._diag_pub.publish(msg)

