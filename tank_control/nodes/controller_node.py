"""controller_node: a core controller kind (parameter ``controller``) sampled on the ROS 2 graph.

Subscribes ``measurement``, ``setpoint`` (and ``disturbance`` when the kind uses measured
disturbances) and the plant's latched ``applied_input`` (a controller that starts on a running
loop takes over from it, bumplessly); publishes ``manipulated``, ``/diagnostics``,
``~/late_inputs``, the kind's state topic; writes the kind's results (e.g. ``robustness.*``, ``autotune.*``) to
read-only parameters and ``/diagnostics``; offers the kind's commands as ``std_srvs/Trigger`` services.
Samples on each measurement's arrival (``wall``, ``trigger: measurement``), on a timer (``wall``
with ``trigger: timer``, ``sim``) or answers each plant tick (``lockstep``): the clock protocol
is ``nodes/protocol/controller.py``, picked once from ``clock_mode``; warm start,
measurement faults and fail-safe as in docs/nodes.md ("controller_node"). This module wires
subscriptions, timers and publishers; input checks, reports and parameter handling are its
base classes (``controller_inputs``, ``controller_reports``, ``controller_params``).
Units: those of the channels; times in s.
"""
from __future__ import annotations

import functools
import math
import sys
import time
from collections.abc import Mapping
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from tank_control.core import node_specs
from tank_control.core.control.kinds import registry
from tank_control.core.interfaces import seconds, to_ns
from tank_control.core.scenario import controller_setup
from tank_control.core.loop import warm_start
from tank_control.core.stamps import FutureStamps, future_tolerance_ns
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.controller_params import ControllerParams
from tank_control.nodes.controller_reports import SATURATION_WARN_SAMPLES  # noqa: F401 (API)
from tank_control.nodes.loop_performance import LoopPerformance
from tank_control.nodes.messages import (APPLIED_QOS, LATE_QOS, ORIGIN_QOS, SIGNAL_QOS,
                                         TOPIC_APPLIED_INPUT, TOPIC_DIAGNOSTICS,
                                         TOPIC_DISTURBANCE, TOPIC_LATE_INPUTS,
                                         TOPIC_MANIPULATED, TOPIC_MEASUREMENT, TOPIC_SETPOINT,
                                         TOPIC_TIME_ORIGIN,
                                         quiet_publisher_events, quiet_subscription_events,
                                         reliable_qos, stamp_to_ns, to_joint_state)
from tank_control.nodes.cdr import JointStateCdr
from tank_control.nodes.params import ParameterBinding
from tank_control.nodes.protocol.controller import Outputs, controller_clock, resolved_mode
from tank_control.nodes.runtime import duplicate_name_problem
from tank_control.nodes.runtime import main as run_node_main

#: State topic of a kind with a state machine: reliable, transient local, keep-last 10 (a
#: one-sample state such as ``tuned`` is not overwritten before delivery); a late subscriber
#: gets the recent states, the last one is the current state.
STATE_QOS = reliable_qos(10, latched=True)
#: longest wait for the plant's ``applied_input`` before the first sample on a running loop
#: (wall clock) [s]; then the controller starts from ``initial_output`` (logged)
TAKEOVER_WAIT_S = 2.0


class ControllerNode(ControllerParams):
    """Thin adapter: parameters → core controller → clock protocol → messages."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('controller', allow_undeclared_parameters=True, **kwargs)
        self._u = None                             # last published output
        self._started = False                      # warm start done (first good sample)
        kind_name = self._kind_from_overrides()
        self._kind = registry.get_kind(kind_name)
        self._kind_names = frozenset(s.name for s in self._kind.specs())
        self._prepared = None                      # (change, _gen)
        self._gen = 0                 # bumped whenever the running controller steps or resets
        self._r_seen: np.ndarray | None = None     # the setpoint of the last sample
        self._causes = {}             # a test's failure reason → with its likely cause
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
        # the clock protocol (nodes/protocol/controller.py): wall samples on each
        # measurement's arrival (the timer watches for stale ones) or on the timer
        mode = resolved_mode(str(values['clock_mode']),
                             bool(self.get_parameter('use_sim_time').value))
        protocol = controller_clock(mode, str(values['trigger']))
        # wall: costly work runs off the sampling path (nodes/live_rebuild.py, relay designs)
        self._wall = protocol.real_time
        self._mark_clock(self._controller)
        # inputs stamped more than max_future_stamp ahead of this node's now are refused
        # (core/stamps.py): one would hold every later input as "older" (docs/nodes.md)
        self._future = FutureStamps(future_tolerance_ns(
            values['max_future_stamp'], self._controller.sample_time, protocol.ticks))
        self._protocol = protocol(self, to_ns(self._controller.sample_time), self._outputs,
                               self._disturbances, self._future)
        #: called after each sample with (plant time [ns], y, r, d, u, fault) — fault '' for a
        #: good sample, else why the output was held — a hook for features: loop monitoring
        #: (nodes/loop_performance.py) is one
        self.sample_observers: list[Any] = []
        self._performance = LoopPerformance(self, lambda: self._params.values, self._kind,
                                            self._controller.sample_time, self._outputs,
                                            self._inputs)
        self.sample_observers.append(
            lambda t_ns, y, r, d, u, fault: self._performance.sample(
                t_ns, y, r, u, self._controller.status.get('mode') == 'manual', fault))

        self._fault = ''         # '' | 'stale' | 'non-finite' | 'out-of-range' | 'controller'
        self._fault_reason = ''
        self._update_error = ''          # a parameter change that could not be applied
        self._last_sample_io = None
        self._logged = set()
        self.counters = {'samples': 0, 'stale_samples': 0, 'nonfinite_measurements': 0,
                         'out_of_range_measurements': 0, 'rejected_inputs': 0,
                         'late_setpoints': 0, 'fault_episodes': 0, 'update_errors': 0,
                         'controller_faults': 0, 'rejected_future': 0, 'unknown_channels': 0,
                         'empty_inputs': 0, 'nonfinite_values': 0, 'rejected_past': 0}
        self._limited = set()   # kinds of input reasons logged this diagnostics period
        self._compute_s = math.nan
        self._saturated_samples = 0                # consecutive samples at an input limit
        # take-over: the plant's applied manipulated values (None: not heard yet) by plant
        # session (header.frame_id): a dead plant's latched sample may still come; the wall
        # time the first sample started waiting for them
        self._applied: dict[str, dict[str, float]] = {}
        self._session = ''                         # the session of the latest measurement
        self._takeover_since: float | None = None

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
        self._reference_subs = [
            self.create_subscription(JointState, topic,
                                     functools.partial(self._on_reference, topic), SIGNAL_QOS,
                                     event_callbacks=quiet_subscription_events(), raw=True)
            for topic in (TOPIC_SETPOINT, TOPIC_DISTURBANCE)[:2 if self._disturbances else 1]]
        self._state_pub = None
        if self._kind.state is not None:
            self._state_pub = self.create_publisher(
                String, '~/' + self._kind.state.replace('.', '_'), STATE_QOS)
            self._state_pub.publish(String(data=str(self._params.values[self._kind.state])))
        for command in self._kind.commands:
            self.create_service(Trigger, f'~/{command}',
                                functools.partial(self._on_command, command))
        if self._protocol.sample_timer:
            self._timer = self.create_timer(self._controller.sample_time,
                                            lambda: self._emit(self._protocol.timer()))
        self.create_timer(float(values['diagnostics_period']), self._publish_diagnostics,
                          clock=steady_clock())
        self._matched_sent = None          # in the last /diagnostics
        self._prestart_calls = 0           # the harness waits for them: _on_prestart
        self._prestart_timer = self.create_timer(0.02, self._on_prestart, clock=steady_clock())
        self.get_logger().info(
            f'{kind_name} controller ({self._kind.description}), {mode} clock, sample_time '
            f'{self._controller.sample_time:g} s, reads {list(self._outputs)}, '
            f'writes {list(self._inputs)}')
        self._warning = ''
        self._check_warning()

    # ---------------------------------------------------------------- inputs
    def _emit(self, outputs: Outputs) -> None:
        """Publish what the clock protocol answered: ``manipulated`` stamped."""
        for t_ns, u in outputs:
            self._pub.publish(self._manipulated_cdr.encode_ns(t_ns, u))

    def _on_measurement(self, msg: bytes) -> None:
        parsed = self._parse(TOPIC_MEASUREMENT, msg)
        if parsed is None:
            return
        t_ns, values, self._session = parsed
        self._count_channels(TOPIC_MEASUREMENT, values, self._outputs)
        mine = {name: values[name] for name in self._outputs if name in values}
        self._emit(self._protocol.measurement(t_ns, mine))

    def _on_reference(self, topic: str, msg: bytes) -> None:
        """A setpoint or measured disturbance message (CDR bytes of a JointState)."""
        parsed = self._parse(topic, msg)
        if parsed is None:
            return
        setpoint = topic == TOPIC_SETPOINT
        self._count_channels(topic, parsed[1], self._outputs if setpoint else self._disturbances)
        take = self._protocol.setpoint if setpoint else self._protocol.disturbance
        self._emit(take(parsed[0], parsed[1]))

    def _on_applied(self, msg: bytes) -> None:
        """The plant's latched applied manipulated values (an empty message: none yet), kept per
        plant session (``header.frame_id``, also on its measurements). Only read before the
        first sample (``takeover``): once started the plant's values (one per tick in
        lockstep) are not decoded."""
        if self._started:
            return
        parsed = self._parse(TOPIC_APPLIED_INPUT, msg)
        if parsed is None:
            return
        self._applied[parsed[2]] = {n: v for n, v in parsed[1].items() if math.isfinite(v)}
        self._emit(self._protocol.applied())        # lockstep: the tick that waited for it

    def _on_origin(self, msg: Time) -> None:
        """wall: the plant's time origin (a new one when the plant restarted). sim/lockstep:
        an origin other than 0 comes from a plant on the wall clock, which publishes no
        /clock ticks to answer: /diagnostics ERROR with the remedy."""
        origin = stamp_to_ns(msg)
        conflict = (f'the plant runs on the wall clock (time_origin {origin} ns) but this '
                    f'node samples in {self._protocol.mode} (clock_mode '
                    f'{self._params.values["clock_mode"]}, use_sim_time '
                    f'{self.get_parameter("use_sim_time").value}): it will never sample; start '
                    'it with clock_mode wall and use_sim_time false'
                    ) if self._protocol.origin(origin) else ''
        self.counters['rejected_future'] = self._future.refused    # an origin far ahead too
        if conflict != self._clock_conflict:
            self._clock_conflict = conflict
            if conflict:
                self.get_logger().error(conflict)
            self._publish_diagnostics()

    # ------------------------------------------- the host of the clock protocol
    @property
    def started(self) -> bool:
        return self._started

    @property
    def last_output(self) -> np.ndarray | None:
        return self._u

    @property
    def stale_limit(self) -> int:
        return int(self._params.values['stale_samples'])

    def clock_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def accept(self, topic: str, values: Mapping[str, float], names: tuple[str, ...],
               last: dict[str, float]) -> dict[str, float]:
        return self._finite_or_last(topic, values, names, last)

    def info(self, text: str) -> None:
        self.get_logger().info(text)

    def warning(self, text: str) -> None:
        self.get_logger().warning(text)

    def late_setpoint(self, t_ns: int, names: list[str], used: list[float]) -> None:
        """wall/sim: a setpoint stamped at or before the latest sample came too late for it."""
        self.counters['late_setpoints'] += 1
        self._late_pub.publish(to_joint_state(t_ns, names, used))

    def new_session(self, t_ns: int, last_ns: int) -> None:
        """A plant that (re)started: its tick 0 after later ticks (lockstep), or a measurement
        stamped before the previous one (sim: /clock went back). The protocol dropped the old
        session's bookkeeping, so the new ticks are not taken for late duplicates; the
        controller's state continues (its output does not jump)."""
        self.get_logger().info('new plant session (its clock restarted at 0): ticks answered '
                               'from 0 again, control continues from the current state')
        self._abort_test('the plant restarted (its clock went back to '
                         f'{seconds(t_ns):g} s from {seconds(last_ns):g} s) during the test')

    def on_name_conflict(self, problem: str) -> None:
        """``runtime.NameWatch``: another node of this name joined the graph."""
        self._abort_test(problem)
        self._name_late_cause(problem)      # a test that failed just before: named as cause

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

    def takeover(self, t_ns: int) -> tuple[bool, np.ndarray | None]:
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
                    or (self._protocol.ticks and t_ns > 0))
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

    # -------------------------------------------------------------- sampling
    def sample(self, t_ns: int, y: Mapping[str, float], r: Mapping[str, float],
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
            return self._observed(t_ns, y_vec, r_vec, d_vec, self._hold(fault), fault)
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
            return self._observed(t_ns, y_vec, r_vec, d_vec, self._hold('controller'),
                                  'controller')
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
        return self._observed(t_ns, y_vec, r_vec, d_vec, u, '')

    def _observed(self, t_ns: int, y: np.ndarray, r: np.ndarray, d: np.ndarray, u: np.ndarray,
                  fault: str) -> np.ndarray:
        """``u`` after the sample observers have seen the sample."""
        for observe in self.sample_observers:
            observe(t_ns, y, r, d, u, fault)
        return u


def main(args: list[str] | None = None) -> int:
    """Console entry point controller_node; exit 2 with a one-line reason on bad parameters."""
    return run_node_main('controller_node', ControllerNode, args)


if __name__ == '__main__':
    sys.exit(main())
