"""controller_node: a core controller kind (parameter ``controller``) sampled on the ROS 2 graph.

Subscribes ``measurement``, ``setpoint`` (and ``disturbance`` when the kind uses measured
disturbances) and the plant's latched ``applied_input`` (a controller that starts on a running
loop takes over from it, bumplessly); publishes ``manipulated``, ``/diagnostics``,
``~/late_inputs``, the kind's state topic; writes the kind's results (e.g. ``robustness.*``, ``autotune.*``) to
read-only parameters and ``/diagnostics``; offers the kind's commands as ``std_srvs/Trigger`` services.
Samples on each measurement's arrival (``wall``, ``trigger: measurement``), on a timer (``wall``
with ``trigger: timer``, ``sim``) or answers each plant tick (``lockstep``); warm start,
measurement faults and fail-safe as in docs/nodes.md ("controller_node"). Units: those of the channels; times in s.
"""
from __future__ import annotations

import math
import sys
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from tank_control.core import node_specs, ranges
from tank_control.core.control.kinds import registry
from tank_control.core.interfaces import seconds, to_ns
from tank_control.core.params import ConfigError
from tank_control.core.scenario import controller_setup
from tank_control.core.loop import warm_start
from tank_control.core.stamps import FutureStamps, future_tolerance_ns
from tank_control.nodes.clock import (Answers, Scheduled, StampedInbox, is_sample_instant,
                                      sim_sample_instant, steady_clock)
from tank_control.nodes.messages import (APPLIED_QOS, LATE_QOS, ORIGIN_QOS, SIGNAL_QOS,
                                         TOPIC_APPLIED_INPUT, TOPIC_DIAGNOSTICS,
                                         TOPIC_DISTURBANCE, TOPIC_LATE_INPUTS,
                                         TOPIC_MANIPULATED, TOPIC_MEASUREMENT, TOPIC_SETPOINT,
                                         TOPIC_TIME_ORIGIN, parse_signal,
                                         quiet_publisher_events, quiet_subscription_events,
                                         reliable_qos, stamp_to_ns, to_joint_state)
from tank_control.nodes.cdr import JointStateCdr
from tank_control.nodes.params import ParameterBinding, ParameterError
from tank_control.nodes.runtime import duplicate_name_problem
from tank_control.nodes.runtime import main as run_node_main

#: State topic of a kind with a state machine: reliable, transient local, keep-last 10 (a
#: one-sample state such as ``tuned`` is not overwritten before delivery); a late subscriber
#: gets the recent states, the last one is the current state.
STATE_QOS = reliable_qos(10, latched=True)
#: consecutive samples with an input at its limit after which /diagnostics says WARN
SATURATION_WARN_SAMPLES = 20
#: longest wait for the plant's ``applied_input`` before the first sample on a running loop
#: (wall clock) [s]; then the controller starts from ``initial_output`` (logged)
TAKEOVER_WAIT_S = 2.0


class ControllerNode(Node):
    """Thin adapter: parameters → core controller → timer/lockstep → messages."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('controller', allow_undeclared_parameters=True, **kwargs)
        self._u: np.ndarray | None = None          # last published output
        self._started = False                      # warm start done (first good sample)
        kind_name = self._kind_from_overrides()
        self._kind = registry.get_kind(kind_name)
        self._kind_names = frozenset(s.name for s in self._kind.specs())
        self._prepared: tuple[registry.PreparedChange, int] | None = None   # (change, _gen)
        self._gen = 0                 # bumped whenever the running controller steps or resets
        self._r_seen: np.ndarray | None = None     # the setpoint of the last sample
        self._causes: dict[str, str] = {}   # a test's failure reason → with its likely cause
        self._params = ParameterBinding(
            self, node_specs.controller_specs(kind_name, self._override_values()),
            cross_check=self._cross_check, derive=self._derive)
        values = self._params.values
        setup = controller_setup(values)
        self._controller = setup.build_controller()
        self._ranges = setup.ranges
        self._params.take_pending()
        self.add_post_set_parameters_callback(self._on_params_set)
        self._outputs = tuple(self._controller.output_names)
        self._inputs = tuple(self._controller.input_names)
        self._disturbances = tuple(self._controller.disturbance_names)
        self._ts_ns = to_ns(self._controller.sample_time)
        self._mode = str(values['clock_mode'])
        if self._mode == 'auto':       # the harness passes use_sim_time in sim and lockstep
            sim = bool(self.get_parameter('use_sim_time').value)
            self._mode = 'lockstep' if sim else 'wall'
        # wall: sample on each measurement's arrival (the timer watches for stale ones) or on
        # the timer; sim and lockstep have their own rule
        self._on_arrival = self._mode == 'wall' and values['trigger'] == 'measurement'
        self._last_instant: int | None = None      # wall, on arrival: index of the last sample
        # wall: stamp of the last output published [ns]; a new plant session (new origin) may
        # put its first instants before it, and the outputs' stamps must not go back
        self._last_out_ns: int | None = None

        # latest inputs (wall/sim) and fault bookkeeping
        self._y: dict[str, float] = {}
        self._r: dict[str, float] = {}
        # measured disturbances: a channel never received is passed as NaN, and the
        # controller substitutes its own value (mpcs: the operating point mpcs.op.F_D/T_D)
        self._d: dict[str, float] = {name: math.nan for name in self._disturbances}
        self._fresh = False
        self._since_measurement = 0
        self._fault = ''         # '' | 'stale' | 'non-finite' | 'out-of-range' | 'controller'
        self._fault_reason = ''
        self._update_error = ''          # a parameter change that could not be applied
        self._last_sample_io: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._logged: set[str] = set()
        self.counters = {'samples': 0, 'stale_samples': 0, 'nonfinite_measurements': 0,
                         'out_of_range_measurements': 0, 'rejected_inputs': 0,
                         'late_setpoints': 0, 'fault_episodes': 0, 'update_errors': 0,
                         'controller_faults': 0, 'rejected_future': 0, 'unknown_channels': 0,
                         'empty_inputs': 0, 'nonfinite_values': 0}
        # inputs stamped more than max_future_stamp ahead of this node's now are refused
        # (core/stamps.py): one would hold every later input as "older" (docs/nodes.md)
        self._future = FutureStamps(future_tolerance_ns(
            values['max_future_stamp'], self._controller.sample_time, self._mode == 'lockstep'))
        self._limited: set[str] = set()   # kinds of input reasons logged this diagnostics period
        # plant time base: origin of the stamps (wall: from the plant, None until then)
        self._origin_ns: int | None = None if self._mode == 'wall' else 0
        self._r_stamp: int | None = None           # stamp of the setpoint held (wall/sim)
        # wall: setpoint / disturbance values that came ahead of their instant (the reference's
        # wall.lead), taken at the first sample at or after their stamp; their last valid values
        self._r_ahead, self._d_ahead = Scheduled(), Scheduled()
        self._r_valid: dict[str, float] = {}
        self._d_valid: dict[str, float] = {}
        self._last_sample: tuple[int, dict[str, float]] | None = None   # (plant time, r used)
        self._compute_s = math.nan
        self._saturated_samples = 0                # consecutive samples at an input limit
        # take-over: the plant's applied manipulated values (None: not heard yet), the wall
        # time the first sample started waiting for them, the lockstep tick left unanswered
        # by plant session (header.frame_id): a dead plant's latched sample may still come
        self._applied: dict[str, dict[str, float]] = {}
        self._session = ''                         # the session of the latest measurement
        self._takeover_since: float | None = None
        self._deferred_tick: int | None = None
        self._last_y_stamp: int | None = None      # wall/sim: stamp of the latest measurement
        self._sim_instant: int | None = None       # sim: the latest timer call's instant [ns]

        self._pub = self.create_publisher(JointState, TOPIC_MANIPULATED, SIGNAL_QOS,
                                          event_callbacks=quiet_publisher_events())
        self._manipulated_cdr = JointStateCdr(self._inputs)   # pre-encoded (nodes/cdr.py)
        self._late_pub = self.create_publisher(JointState, TOPIC_LATE_INPUTS, LATE_QOS)
        # wall: the loop's time base; sim/lockstep: a check that the plant is not on the wall
        # clock (its origin is then not 0), which would leave this node waiting for good
        self.create_subscription(Time, TOPIC_TIME_ORIGIN, self._on_origin, ORIGIN_QOS)
        # signal inputs are taken as CDR bytes and decoded directly (nodes/cdr.py)
        self.create_subscription(JointState, TOPIC_APPLIED_INPUT, self._on_applied, APPLIED_QOS,
                                 raw=True)
        self._clock_conflict = ''
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self.create_subscription(JointState, TOPIC_MEASUREMENT, self._on_measurement, SIGNAL_QOS,
                                 event_callbacks=quiet_subscription_events(), raw=True)
        # the reference's signals: their matched writers are reported (_matched)
        self._reference_subs = [self.create_subscription(
            JointState, TOPIC_SETPOINT, self._on_setpoint, SIGNAL_QOS,
            event_callbacks=quiet_subscription_events(), raw=True)]
        if self._disturbances:
            self._reference_subs.append(self.create_subscription(
                JointState, TOPIC_DISTURBANCE, self._on_disturbance, SIGNAL_QOS,
                event_callbacks=quiet_subscription_events(), raw=True))
        required: dict[str, tuple[str, ...]] = {'measurement': self._outputs,
                                                'setpoint': self._outputs}
        if self._disturbances:
            required['disturbance'] = ()   # arrival is enough; missing channels keep last values
        # lockstep: the reference's topics are zero-order-hold streams (nodes/clock.Held)
        self._inbox = StampedInbox(required, held=('setpoint', 'disturbance'))
        self._measured_ns: int | None = None   # lockstep: the latest measurement's stamp
        self._behind_ns: int | None = None     # lockstep: a tick seen before the last answered
        self._answers = Answers()
        self._state_pub = None
        if self._kind.state is not None:
            self._state_pub = self.create_publisher(
                String, '~/' + self._kind.state.replace('.', '_'), STATE_QOS)
            self._state_pub.publish(String(data=str(self._params.values[self._kind.state])))
        for command in self._kind.commands:
            self.create_service(Trigger, f'~/{command}',
                                lambda request, response, c=command: self._on_command(c, response))
        if self._mode != 'lockstep':
            self._timer = self.create_timer(self._controller.sample_time, self._on_timer)
        self.create_timer(float(values['diagnostics_period']), self._publish_diagnostics,
                          clock=steady_clock())
        self._matched_sent: dict[str, int] | None = None   # in the last /diagnostics
        self._prestart_calls = 0           # the harness waits for them: _on_prestart
        self._prestart_timer = self.create_timer(0.02, self._on_prestart, clock=steady_clock())
        self.get_logger().info(
            f'{kind_name} controller ({self._kind.description}), {self._mode} clock, sample_time '
            f'{self._controller.sample_time:g} s, reads {list(self._outputs)}, '
            f'writes {list(self._inputs)}')
        self._warning = ''
        self._check_warning()

    # ------------------------------------------------------------ parameters
    def _kind_from_overrides(self) -> str:
        override = getattr(self, '_parameter_overrides', {}).get('controller')
        try:
            return node_specs.kind_of('controller', {} if override is None
                                      else {'controller': override.value})
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None

    def _override_values(self) -> dict[str, Any]:
        return {name: p.value for name, p in getattr(self, '_parameter_overrides', {}).items()}

    def _cross_check(self, values: Mapping[str, Any], changed: frozenset[str]) -> str | None:
        # the node's own results (tuned gains, an identified model) are not a user's change:
        # they are checked as values, not against a guard on changes (robustness.ms_max)
        writing = getattr(self, '_params', None) is not None and self._params.writing
        given = frozenset() if writing else changed
        try:
            setup = controller_setup(values, given=given)
        except ConfigError as exc:
            return str(exc)
        mine = changed & self._kind_names
        if writing or not mine or getattr(self, '_controller', None) is None:
            return None
        # a user's change of the controller: build the candidate now and try it from the last
        # sample (the derived quantities must give finite outputs); it takes effect next sample
        if self._prepared is not None and self._prepared[1] == self._gen:
            mine |= self._prepared[0].changed          # accepted earlier, not applied yet
        try:
            prepared = registry.prepare_change(
                self._kind, self._controller, setup.settings, frozenset(mine),
                trial=self._last_sample_io, u_last=self._u)
        except ValueError as exc:
            return str(exc)
        self._prepared = (prepared, self._gen)
        return None

    def _on_params_set(self, parameters: list) -> None:
        """Accepted ``range.*`` changes act at once (on the next message)."""
        given = {p.name: p.value for p in parameters if p.name.startswith(ranges.PREFIX)}
        if given:
            values = {**self._params.values, **given}
            self._ranges = ranges.ranges_from(values, tuple(self._ranges.bounds))

    def _derive(self, values: Mapping[str, Any], changed: frozenset[str]) -> dict[str, Any]:
        extra = {}
        if self._kind.derive is not None:
            kind_values = {k: v for k, v in values.items() if k in self._kind_names}
            extra = {k: v for k, v in self._kind.derive(kind_values).items() if k not in changed}
        # auto → manual without a manual_output: keep the current output (bumpless)
        if ('mode' in changed and values.get('mode') == 'manual' and 'manual_output' not in changed
                and isinstance(values.get('manual_output'), float) and self._u is not None
                and self._u.size == 1):
            lo, hi = values.get('u_min', -math.inf), values.get('u_max', math.inf)
            extra['manual_output'] = float(min(max(self._u[0], lo), hi))
        return extra

    def _step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        """One controller step; accepted parameter changes take effect at it, bumplessly."""
        changed = [name for name in self._params.take_pending() if name in self._kind_names]
        prepared, self._prepared = self._prepared, None
        gen, self._gen = self._gen, self._gen + 1
        if changed:
            try:
                # the candidate checked on acceptance, unless it is a copy of a running
                # controller that has stepped or reset since (then it is made anew)
                if prepared is None or (prepared[0].in_place and prepared[1] != gen):
                    settings = controller_setup(self._params.values, given=()).settings
                    prepared = (registry.prepare_change(self._kind, self._controller, settings,
                                                        frozenset(changed)), gen)
                self._controller, u = prepared[0].take_effect(self._controller, t, y, r, d)
                self._update_error = ''
                return u
            except ValueError as exc:    # checked before acceptance; never expected
                self.counters['update_errors'] += 1
                self._update_error = f'parameter change could not be applied: {exc}'
                self.get_logger().error(self._update_error)
                self._publish_diagnostics()
        return np.asarray(self._controller.step(t, y, r, d), dtype=float)

    # ---------------------------------------------------------------- inputs
    def _parse(self, topic: str, msg: bytes) -> tuple[int, dict[str, float], str] | None:
        """``(stamp_ns, {channel: value}, header.frame_id)`` of an input (CDR bytes of a
        JointState), None when malformed (also more than ``MAX_NAMES`` names) or stamped more
        than ``max_future_stamp`` ahead of this node's now (each counted and logged, at most
        once per diagnostics period)."""
        try:
            t_ns, frame_id, names, values = parse_signal(msg)
        except ValueError as exc:
            self.counters['rejected_inputs'] += 1
            self._log_limited(f'{topic}/malformed', f'{topic}: malformed message ignored ({exc})')
            return None
        # lockstep: the plant publishes tick k+1 only once tick k is answered, so a measurement
        # is at most one plant tick (<= this controller's sample time) past the latest one
        tolerance = (self._ts_ns if self._mode == 'lockstep' and topic == TOPIC_MEASUREMENT
                     else None)
        admitted = self._future.admit(topic, t_ns, self._now_ns(), time.monotonic_ns(),
                                      tolerance)
        for text in self._future.take_report():
            self.get_logger().warning(text + ' (logged at most once per diagnostics period)')
        if not admitted:
            self.counters['rejected_future'] = self._future.refused
            return None
        return t_ns, dict(zip(names, values)), frame_id

    def _now_ns(self) -> int | None:
        """This node's now in the stamps' time base (None: not known yet): wall its clock,
        sim its /clock time, lockstep the latest measured tick."""
        if self._mode == 'lockstep':
            return self._measured_ns
        now = self.get_clock().now().nanoseconds
        return None if self._mode == 'sim' and now == 0 else now

    def _count_channels(self, topic: str, values: Mapping[str, float],
                        known: tuple[str, ...]) -> None:
        """Count (and log, rate-limited) what an input carries that this controller does not
        use: unknown channels, a message with none of its channels, non-finite values."""
        unknown = [n for n in values if n not in known]
        if unknown:
            self.counters['unknown_channels'] += len(unknown)
            shown = ', '.join(repr(n[:40]) for n in unknown[:3])
            more = f' and {len(unknown) - 3} more' if len(unknown) > 3 else ''
            self._log_limited(f'{topic}/unknown', f'{topic}: unknown channel(s) {shown}{more} '
                              f'ignored ({self.counters["unknown_channels"]} so far); known: '
                              f'{", ".join(known) or "none"}')
        if known and not any(n in values for n in known):
            self.counters['empty_inputs'] += 1
            self._log_limited(f'{topic}/empty', f'{topic}: message without any of the channels '
                              f'{", ".join(known)} ignored ({self.counters["empty_inputs"]} so '
                              'far)')
        nonfinite = [n for n in known if n in values and not math.isfinite(values[n])]
        if nonfinite:
            self.counters['nonfinite_values'] += len(nonfinite)
            self._log_limited(f'{topic}/nonfinite', f'{topic}: non-finite value for '
                              f'{", ".join(map(repr, nonfinite))} '
                              f'({self.counters["nonfinite_values"]} so far)')

    def _log_limited(self, key: str, text: str) -> None:
        """Log ``text`` unless a reason of kind ``key`` was logged this diagnostics period."""
        if key not in self._limited:
            self._limited.add(key)
            self.get_logger().warning(text + ' (logged at most once per diagnostics period)')

    def _reject_input(self, reason: str) -> None:
        self.counters['rejected_inputs'] += 1
        self._log_once(reason)

    def _log_once(self, text: str) -> None:
        if text not in self._logged:
            self._logged.add(text)
            self.get_logger().warning(text)

    def _finite_or_last(self, topic: str, values: Mapping[str, float], names: tuple[str, ...],
                        last: dict[str, float]) -> dict[str, float]:
        """Channels ``names`` from ``values``; a non-finite one or one outside its
        ``range.*`` is rejected (last valid kept)."""
        out = {}
        for name in names:
            if name not in values:
                continue
            reason = self._ranges.reason(name, values[name])
            if reason is None:
                out[name] = last[name] = values[name]
            else:
                self._reject_input(f'{topic}: {reason} ignored; last valid kept')
                if name in last:
                    out[name] = last[name]
        return out

    def _measurement_fault(self, y: np.ndarray) -> str:
        """'' for a good measurement, else 'non-finite' or 'out-of-range' (logged once)."""
        for name, value in zip(self._outputs, y.tolist()):
            reason = self._ranges.reason(name, value)
            if reason is not None:
                if math.isfinite(value):
                    self._log_once(f'{TOPIC_MEASUREMENT}: {reason} refused like a non-finite '
                                   'one (logged once)')
                    return 'out-of-range'
                return 'non-finite'
        return ''

    def _on_measurement(self, msg: bytes) -> None:
        parsed = self._parse(TOPIC_MEASUREMENT, msg)
        if parsed is None:
            return
        t_ns, values, self._session = parsed
        self._count_channels(TOPIC_MEASUREMENT, values, self._outputs)
        mine = {name: values[name] for name in self._outputs if name in values}
        self._check_new_session(t_ns)
        if self._mode == 'lockstep':
            self._inbox.put('measurement', t_ns, mine)   # non-finite kept: the sample handles it
            self._measured_ns = t_ns
            self._maybe_answer(t_ns, resent=True)
            return
        self._y.update(mine)
        if len(mine) == len(self._outputs):
            self._fresh = True
            if self._on_arrival:
                self._sample_on_arrival(t_ns)

    def _on_setpoint(self, msg: bytes) -> None:
        parsed = self._parse(TOPIC_SETPOINT, msg)
        if parsed is None:
            return
        t_ns = parsed[0]
        self._count_channels(TOPIC_SETPOINT, parsed[1], self._outputs)
        if self._mode != 'lockstep':
            self._check_late_setpoint(t_ns, parsed[1])
            if self._r_stamp is not None and t_ns < self._r_stamp:
                if not self._future.back_on_clock(TOPIC_SETPOINT, self._r_stamp, t_ns,
                                                  self._now_ns()):
                    return      # older than the setpoint held (out of order): not taken
                self._r_ahead.clear()       # the stepped values waiting for their stamps
                for text in self._future.take_report():
                    self.get_logger().warning(text)
            self._r_stamp = t_ns
        if self._mode == 'wall':
            self._r_ahead.put(t_ns, self._finite_or_last(TOPIC_SETPOINT, parsed[1], self._outputs,
                                                         self._r_valid))
            return
        values = self._finite_or_last(TOPIC_SETPOINT, parsed[1], self._outputs, self._r)
        if self._mode == 'lockstep':
            self._inbox.put('setpoint', t_ns, values)
            self._answer_measured()

    def _check_new_session(self, t_ns: int) -> None:
        """A plant that (re)started: its tick 0 after later ticks (lockstep), or a measurement
        stamped before the previous one (sim: /clock went back). The bookkeeping of the old
        session (answers, inputs stamped at or after the last tick answered, the stamps of
        held values) is dropped, so the new ticks are not taken for late duplicates; the
        controller's state continues (its output does not jump)."""
        if self._mode == 'lockstep':
            last = self._answers.stamp
            if t_ns != 0 or last is None or last <= 0:
                return
            self._answers = Answers()
            self._inbox.drop_from(last)
            self._deferred_tick = None
        else:
            last = self._last_y_stamp
            self._last_y_stamp = t_ns
            if last is None or t_ns >= last:
                return
            self._r_stamp = None
            self._last_sample = None
        self.get_logger().info('new plant session (its clock restarted at 0): ticks answered '
                               'from 0 again, control continues from the current state')
        self._abort_test('the plant restarted (its clock went back to '
                         f'{seconds(t_ns):g} s from {seconds(last):g} s) during the test')

    def on_name_conflict(self, problem: str) -> None:
        """``runtime.NameWatch``: another node of this name joined the graph."""
        self._abort_test(problem)

    def _abort_test(self, cause: str) -> None:
        """A running auto-tune test ends (aborted, previous gains restored) with ``cause`` as
        its reason, instead of failing later for what the cause did to the signals (a second
        reference's setpoints, a restarted plant's jump). Nothing without a running test."""
        abort = getattr(self._controller, 'abort', None)
        if abort is None:
            return
        accepted, _ = abort(cause)
        if accepted:
            self._gen += 1
            self.get_logger().error(f'auto-tune test aborted: {cause}')
            self._write_results()

    def _on_applied(self, msg: bytes) -> None:
        """The plant's latched applied manipulated values (an empty message: none yet), kept per
        plant session (``header.frame_id``, also on its measurements). Only read before the
        first sample (``_takeover``): once started the plant's values (one per tick in
        lockstep) are not decoded."""
        if self._started:
            return
        parsed = self._parse(TOPIC_APPLIED_INPUT, msg)
        if parsed is None:
            return
        self._applied[parsed[2]] = {n: v for n, v in parsed[1].items() if math.isfinite(v)}
        if self._deferred_tick is not None:    # lockstep: the tick that waited for it
            t_ns, self._deferred_tick = self._deferred_tick, None
            self._maybe_answer(t_ns)

    def _takeover(self, t_ns: int) -> tuple[bool, np.ndarray | None]:
        """Before the first sample: ``(ready, u)`` — ``u`` the plant's applied values of this
        controller's inputs to take over from (a running loop), ``None`` to start from
        ``initial_output`` (a new loop: the plant has applied none of them); not ready while
        they may still be on their way (a plant publishing ``applied_input`` is known but
        its latched message has not come, or a lockstep tick after 0), at most
        ``TAKEOVER_WAIT_S``."""
        applied = self._applied.get(self._session)
        if applied is not None:
            if all(n in applied for n in self._inputs):
                return True, np.array([applied[n] for n in self._inputs], dtype=float)
            return True, None
        may_come = (self.count_publishers(TOPIC_APPLIED_INPUT) > 0
                    or (self._mode == 'lockstep' and t_ns > 0))
        if not may_come:
            return True, None
        now = time.monotonic()
        if self._takeover_since is None:
            self._takeover_since = now
        if now - self._takeover_since < TAKEOVER_WAIT_S:
            return False, None
        self._log_once(f"no {TOPIC_APPLIED_INPUT} from the plant within {TAKEOVER_WAIT_S:g} s: "
                       'starting from initial_output')
        return True, None

    def _check_late_setpoint(self, t_ns: int, values: Mapping[str, float]) -> None:
        """wall/sim: a setpoint stamped at or before the latest sample came too late for it."""
        if self._last_sample is None or self._origin_ns is None:
            return
        sampled_at, r_used = self._last_sample
        if t_ns - self._origin_ns <= sampled_at:
            self.counters['late_setpoints'] += 1
            names = [n for n in self._outputs if n in values]
            self._late_pub.publish(to_joint_state(t_ns, names,
                                                  [r_used.get(n, math.nan) for n in names]))

    def _on_origin(self, msg: Time) -> None:
        """wall: the plant's time origin (a new one when the plant restarted). sim/lockstep:
        an origin other than 0 comes from a plant on the wall clock, which publishes no
        /clock ticks to answer: /diagnostics ERROR with the remedy."""
        origin = stamp_to_ns(msg)
        if self._mode != 'wall':
            conflict = (f'the plant runs on the wall clock (time_origin {origin} ns) but this '
                        f'node samples in {self._mode} (clock_mode {self._params.values["clock_mode"]}'
                        f', use_sim_time {self.get_parameter("use_sim_time").value}): it will never '
                        'sample; start it with clock_mode wall and use_sim_time false'
                        ) if origin != 0 else ''
            if conflict != self._clock_conflict:
                self._clock_conflict = conflict
                if conflict:
                    self.get_logger().error(conflict)
                self._publish_diagnostics()
            return
        if origin != self._origin_ns:
            self.get_logger().info(f'plant time origin {origin} ns: loop time = stamp - origin')
            self._origin_ns = origin
            self._future.reset()            # a new time base: no clock offset carried over
            self._last_sample = None
            self._last_instant = None

    def _on_disturbance(self, msg: bytes) -> None:
        parsed = self._parse(TOPIC_DISTURBANCE, msg)
        if parsed is not None:
            self._count_channels(TOPIC_DISTURBANCE, parsed[1], self._disturbances)
        if parsed is not None and self._mode == 'wall':
            self._d_ahead.put(parsed[0], self._finite_or_last(
                TOPIC_DISTURBANCE, parsed[1], self._disturbances, self._d_valid))
        elif parsed is not None:
            values = self._finite_or_last(TOPIC_DISTURBANCE, parsed[1], self._disturbances,
                                          self._d)
            if self._mode == 'lockstep':
                self._inbox.put('disturbance', parsed[0], values)
                self._answer_measured()

    # -------------------------------------------------------------- sampling
    def _answer_measured(self) -> None:
        """Lockstep: a setpoint or disturbance came (it may complete the latest tick measured;
        one stamped ahead holds for the ticks up to its stamp)."""
        if self._measured_ns is not None:
            self._maybe_answer(self._measured_ns)

    def _maybe_answer(self, t_ns: int, resent: bool = False) -> None:
        """Lockstep: answer tick ``t_ns`` once its inputs are complete (idempotent).

        A measurement of a tick already answered (the plant re-sent it) gets the
        same message again, without recomputation.
        """
        cached = self._answers.get(t_ns)
        if cached is not None:
            if resent:
                self._pub.publish(cached[0])
            return
        if self._answers.stamp is not None and t_ns < self._answers.stamp:
            if not (resent and t_ns == self._behind_ns):
                self._behind_ns = t_ns if resent else self._behind_ns
                return      # a late duplicate of a tick already passed
            # the plant re-sends a tick before the last one answered: it waits for it (the
            # later stamp answered was not its own); answered anew, as a new session
            self.get_logger().warning(
                f'measurement {t_ns} ns re-sent after {self._answers.stamp} ns was answered: '
                'the plant waits for it; ticks answered from it again')
            self._answers = Answers()
            self._inbox.drop_from(t_ns + 1)
        if not self._inbox.complete(t_ns):
            return
        y = self._inbox.values(t_ns, 'measurement')
        r = self._inbox.values(t_ns, 'setpoint')
        d = {**self._d, **self._inbox.values(t_ns, 'disturbance')}
        takeover = None
        if not self._started:
            ready, takeover = self._takeover(t_ns)
            if not ready:
                self._deferred_tick = t_ns     # answered when applied_input comes (or re-sent)
                return
        if is_sample_instant(t_ns, self._ts_ns) or self._u is None:
            u = self._sample(t_ns, y, r, d, stale=False, takeover=takeover)
        else:
            u = self._u
        msg = self._manipulated_cdr.encode_ns(t_ns, u)
        self._answers.remember(t_ns, msg)
        self._inbox.drop_before(t_ns)
        self._pub.publish(msg)

    def _on_timer(self) -> None:
        """wall/sim: one sample with the latest data (wall with ``trigger: measurement``: only
        the stale one, on this controller's grid, when no measurement came for ``stale_samples``).

        sim: rclpy's EventsExecutor may run the timer twice at one instant (two clock updates
        queued before the timer's dispatch): an instant is sampled once. A /clock that goes
        back (a restarted plant) needs nothing here: rcl re-arms the timer one period after
        the new time."""
        if self._mode == 'sim':
            instant = sim_sample_instant(self.get_clock().now().nanoseconds, self._ts_ns)
            if instant == self._sim_instant:
                return
            self._sim_instant = instant
        self._since_measurement = 0 if self._fresh else self._since_measurement + 1
        self._fresh = False
        stale = self._since_measurement >= int(self._params.values['stale_samples'])
        if self._on_arrival and not stale:
            return          # sampled on the measurements' arrival; the timer only watches
        if self._mode == 'wall':
            self._release_ahead(self.get_clock().now().nanoseconds)
        if len(self._y) < len(self._outputs) or len(self._r) < len(self._outputs):
            return          # nothing measured or no setpoint yet: nothing to control
        if self._origin_ns is None:
            return          # wall: the plant's time origin is not known yet
        now = self.get_clock().now().nanoseconds
        t_ns = sim_sample_instant(now, self._ts_ns) if self._mode == 'sim' else now
        if self._on_arrival:     # stale: the fail-safe sample on this controller's grid
            instant = (now - self._origin_ns) // self._ts_ns
            if self._last_instant is not None and instant <= self._last_instant:
                return
            t_ns = self._origin_ns + instant * self._ts_ns
            if self._behind_last_output(t_ns):
                return      # the new session's grid lags the last output: its next instant
            self._last_instant = instant
        takeover = None
        if not self._started:
            ready, takeover = self._takeover(t_ns - self._origin_ns)
            if not ready:
                return      # the plant's applied_input is on its way
        self._last_sample = (t_ns - self._origin_ns, dict(self._r))
        u = self._sample(t_ns - self._origin_ns, self._y, self._r, self._d, stale=stale,
                         takeover=takeover)
        self._last_out_ns = t_ns
        self._pub.publish(self._manipulated_cdr.encode_ns(t_ns, u))

    def _sample_on_arrival(self, t_ns: int) -> None:
        """wall, ``trigger: measurement``: the measurement stamped ``t_ns`` (a plant sample
        instant) just arrived: sample with it and the latest setpoint, publish ``manipulated``
        stamped ``t_ns`` at once — sample, compute and actuate in one cycle, so the plant's
        next tick holds the output computed from its last measurement (the discrete loop of
        core/loop.py, with a computation and transport delay instead of none). Only a
        measurement that reaches a new instant of this controller's grid,
        ``j = floor((t_ns - origin) / sample_time)``, is a sample (a controller slower than the
        plant, a duplicate, or one out of order is not), nor one stamped at or before the
        last output (a restarted plant's first instants may come before the last fail-safe
        sample of the stale period; the outputs' stamps never go back). The setpoint and
        disturbance are those stamped at or before ``t_ns``."""
        self._release_ahead(t_ns)
        if len(self._y) < len(self._outputs) or len(self._r) < len(self._outputs):
            return          # nothing measured or no setpoint yet: nothing to control
        if self._origin_ns is None or t_ns < self._origin_ns:
            return          # the plant's time origin is not known yet (or an older session's)
        instant = (t_ns - self._origin_ns) // self._ts_ns
        if self._last_instant is not None and instant <= self._last_instant:
            return
        if self._behind_last_output(t_ns):
            return
        plant_ns = t_ns - self._origin_ns
        takeover = None
        if not self._started:
            ready, takeover = self._takeover(plant_ns)
            if not ready:
                return      # the plant's applied_input is on its way
        self._last_instant = instant
        self._since_measurement = 0
        self._fresh = False
        self._last_sample = (plant_ns, dict(self._r))
        u = self._sample(plant_ns, self._y, self._r, self._d, stale=False, takeover=takeover)
        self._last_out_ns = t_ns
        self._pub.publish(self._manipulated_cdr.encode_ns(t_ns, u))

    def _behind_last_output(self, t_ns: int) -> bool:
        """wall: an output stamped ``t_ns`` would go back behind the last one (never published),
        unless that one is stamped beyond the tolerance ahead of this node's clock: it answered
        a stream taken through a clock step (core/stamps.py), whose clock has gone back since —
        waiting until real time passes it would hold the loop as long as the step was."""
        last = self._last_out_ns
        if last is None or t_ns > last:
            return False
        now = self._now_ns()
        return now is None or last - now <= self._future.tolerance_ns

    def _release_ahead(self, t_ns: int) -> None:
        """wall: the setpoint and disturbance values stamped at or before ``t_ns`` (absolute)
        take effect (values published ahead of their instant wait until then)."""
        self._r_ahead.release(t_ns, self._r)
        self._d_ahead.release(t_ns, self._d)

    def _sample(self, t_ns: int, y: Mapping[str, float], r: Mapping[str, float],
                d: Mapping[str, float], stale: bool,
                takeover: np.ndarray | None = None) -> np.ndarray:
        """One controller sample at plant time ``t_ns`` (accepted changes take effect) — or
        hold on a fault. The first good sample starts from ``takeover`` (the plant's applied
        input on a running loop), else from ``initial_output``."""
        y_vec = np.array([y[name] for name in self._outputs], dtype=float)
        r_vec = np.array([r[name] for name in self._outputs], dtype=float)
        d_vec = np.array([d.get(name, math.nan) for name in self._disturbances], dtype=float)
        if (self._r_seen is not None and not np.array_equal(r_vec, self._r_seen, equal_nan=True)
                and hasattr(self._controller, 'abort')):
            # A setpoint that changes during an auto-tune test fails it; a second controller
            # of this name (another graph joined) is the likelier cause: named first.
            problem = duplicate_name_problem(self)
            if problem:
                self.on_name_conflict(problem)
        self._r_seen = r_vec
        self.counters['samples'] += 1
        fault = 'stale' if stale else self._measurement_fault(y_vec)
        if fault:
            return self._hold(fault)
        recovered = ''
        if self._fault and self._u is not None:
            self._gen += 1
            self._controller.reset(y_vec, self._u)       # continue from what the plant got
            self._started = True
            recovered = self._fault
        elif not self._started and takeover is not None:   # a running loop: bumpless take-over
            self._gen += 1
            self._controller.reset(y_vec, takeover)
            self._started = True
            self.get_logger().info(f"took over from the plant's applied input "
                                   f'{dict(zip(self._inputs, takeover.tolist()))} at plant time '
                                   f'{t_ns} ns (bumpless)')
        elif not self._started:      # first good sample: reset(y, initial_output), as core/loop.py
            self._gen += 1
            warm_start(self._controller, y_vec)
            self._started = True
        start = time.perf_counter()
        t = seconds(t_ns)
        try:
            u = np.array(self._step(t, y_vec, r_vec, d_vec), dtype=float)
        except (ArithmeticError, ValueError) as exc:
            u = np.full(len(self._inputs), math.nan)
            self._fault_reason = f'{type(exc).__name__}: {exc}'
        self._compute_s = time.perf_counter() - start
        if not np.all(np.isfinite(u)):
            # a controller that cannot compute: the fail-safe path, said loudly
            self._fault_reason = self._fault_reason or f'non-finite output {u.tolist()}'
            return self._hold('controller')
        if recovered:
            what = 'controller' if recovered == 'controller' else 'measurement'
            self.get_logger().info(f'{what} recovered after {recovered} episode; '
                                   'control resumed bumplessly')
            self._fault = ''
            self._publish_diagnostics()
        self._fault_reason = ''
        self._last_sample_io = (t, y_vec, r_vec, d_vec)
        self._u = u
        self._check_saturation()
        self._check_warning()
        self._write_results()
        return u

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
        if changed.get(state) == 'failed' and changed.get(reason_key):
            # A test that failed beside a second controller of this name (another graph
            # joined before the name watch saw it): the failure names it as the likely cause.
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

    def _on_command(self, command: str, response: Trigger.Response) -> Trigger.Response:
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
        if fail_safe:
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

    def _publish_diagnostics(self) -> None:
        self._limited.clear()                 # input reasons are logged again (rate limit)
        self._future.rearm_reports()
        status = dict(self._controller.status)
        level = (DiagnosticStatus.WARN if self._fault or self._warning
                 else DiagnosticStatus.OK)
        waiting = len(self._y) < len(self._outputs) and self._mode != 'lockstep'
        message = (f'controller fault: {self._fault_reason}; holding' if self._fault == 'controller'
                   else f'measurement {self._fault}: holding' if self._fault
                   else 'waiting for measurement' if waiting
                   else "waiting for the plant's time_origin" if self._origin_ns is None
                   else 'running')
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
            'clock_mode': self._mode,
            'trigger': 'measurement' if self._on_arrival else 'timer',
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


def main(args: list[str] | None = None) -> int:
    """Console entry point controller_node; exit 2 with a one-line reason on bad parameters."""
    return run_node_main('controller_node', ControllerNode, args)


if __name__ == '__main__':
    sys.exit(main())
