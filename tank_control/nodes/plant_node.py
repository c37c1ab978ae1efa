"""plant_node: simulates a core plant kind (parameter ``plant``) and is the clock master.

Publishes ``measurement`` (outputs plus seeded noise), ``/clock`` (sim, lockstep),
``time_origin``, ``applied_input`` (latched: what a restarted controller takes over from),
``~/late_inputs``, ``/diagnostics`` (WARN on a stalled loop, naming what it waits for);
subscribes ``manipulated`` and ``disturbance`` by channel name; serves OPC UA with
``opcua.endpoint`` (``nodes/plant_opcua.py``). Clock modes, the lockstep protocol and
``lockstep.paused``: docs/nodes.md; the protocol is ``nodes/protocol/plant.py``, picked once
from ``clock_mode``. Units: those of the plant kind; times in s.
"""
from __future__ import annotations

import functools
import sys
import time
import uuid
from collections.abc import Callable, Mapping
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.core import node_specs, params_file, ranges
from tank_control.core.interfaces import Configurable
from tank_control.core.node_specs import PlantNode as PlantNodeConfig
from tank_control.core.params import ConfigError, names_of
from tank_control.core.plants.noise import NoiseConfig
from tank_control.core.scenario import plant_setup
from tank_control.core.stamps import FutureStamps, future_tolerance_ns
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.messages import (
    APPLIED_QOS, CLOCK_QOS, LATE_QOS, MATCH_WAIT_S, ORIGIN_QOS, RECORDED_QOS, SIGNAL_QOS,
    TOPIC_APPLIED_INPUT, TOPIC_CLOCK, TOPIC_DIAGNOSTICS, TOPIC_DISTURBANCE, TOPIC_LATE_INPUTS,
    TOPIC_MANIPULATED, TOPIC_MEASUREMENT, TOPIC_RECORDED, TOPIC_TIME_ORIGIN, ChannelFilter,
    ns_to_stamp, quiet_publisher_events, quiet_subscription_events, stamp_to_ns, to_joint_state,
    unmatched)
from tank_control.nodes.params import ParameterBinding, ParameterError
from tank_control.nodes.plant_opcua import PlantOpcua
from tank_control.nodes.protocol.plant import (ORIGIN_NOTICE_S, STALL_RESENDS,  # noqa: F401
                                               Timer, plant_clock)
from tank_control.nodes.runtime import main as run_node_main

_NODE_ONLY = frozenset(names_of(PlantNodeConfig)) | frozenset(names_of(NoiseConfig))
_NODE_ONLY_PREFIX = ranges.PREFIX      # range.*: the filters', not the model's


def _controller_values(name: str, argv: list[str] | None = None) -> dict[str, Any] | None:
    """The controller ``name``'s values from this node's ``--params-file`` files."""
    return params_file.node_values_on_command_line(name, sys.argv if argv is None else argv)


class PlantNode(Node):
    """The plant simulation node, clock master of the run (docs/nodes.md)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('plant', allow_undeclared_parameters=True, **kwargs)
        # The model kind decides which parameters exist.
        override = getattr(self, '_parameter_overrides', {}).get('plant')
        try:
            kind = node_specs.kind_of('plant', {} if override is None else {'plant': override.value})
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        # the controller's parameters in the same --params-file (a scenario, the harness's
        # file): its output limits are the inputs' default range.* (core/ranges.py)
        self._controller_values = _controller_values(
            f'{self.get_namespace().rstrip("/")}/controller')
        self._actuator = node_specs.actuator_defaults(self._controller_values)
        self.params = ParameterBinding(
            self, node_specs.plant_specs(kind, self._controller_values),
            cross_check=self._cross_check)
        values = self.params.values
        try:
            setup = plant_setup(values, self._controller_values)
            self.plant = setup.build_plant()
            self.noise = setup.build_noise(len(self.plant.output_names))
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.counters = {'ticks': 0, 'missed_samples': 0, 'resent_ticks': 0, 'ignored_inputs': 0,
                         'late_inputs': 0, 'rejected_changes': 0, 'out_of_range_inputs': 0,
                         'rejected_future': 0, 'unknown_channels': 0, 'oversized_inputs': 0,
                         'rejected_past': 0}
        # the clock protocol (nodes/protocol/plant.py)
        protocol = plant_clock(str(values['clock_mode']))
        # inputs stamped more than max_future_stamp ahead of this plant's now are refused
        # (core/stamps.py): one would hold every later input as "older" (docs/nodes.md)
        self._future = FutureStamps(future_tolerance_ns(
            values['max_future_stamp'], float(values['sample_time']), protocol.ticks))
        self._is_paused = bool(values['lockstep.paused'])

        self.measurement_pub = self.create_publisher(JointState, TOPIC_MEASUREMENT, SIGNAL_QOS,
                                                     event_callbacks=quiet_publisher_events())
        self.clock_pub = (self.create_publisher(Clock, TOPIC_CLOCK, CLOCK_QOS,
                                                event_callbacks=quiet_publisher_events())
                          if protocol.publishes_clock else None)
        self.diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10,
                                               event_callbacks=quiet_publisher_events())
        self.origin_pub = self.create_publisher(Time, TOPIC_TIME_ORIGIN, ORIGIN_QOS)
        self.late_pub = self.create_publisher(JointState, TOPIC_LATE_INPUTS, LATE_QOS)
        # the manipulated values applied, latched: channels a controller sent (none yet: an
        # empty message, so a controller that starts now knows it starts a new loop)
        self.applied_pub = self.create_publisher(JointState, TOPIC_APPLIED_INPUT, APPLIED_QOS)
        # this plant process's session: header.frame_id of its measurements and applied inputs,
        # so a controller takes over from this plant's values, never a dead one's
        self._protocol = protocol(self, self.plant, self.noise, values, self.counters,
                                  self._future, uuid.uuid4().hex[:16])
        self.applied_pub.publish(self._protocol.empty_applied())
        self._stall_logged = ''          # the stall last logged ('' = none: the loop moves)
        # a value outside its range.* is ignored like a non-finite one (last valid kept)
        self.filters = {TOPIC_MANIPULATED: ChannelFilter(self.plant.input_names,
                                                         ranges=setup.ranges),
                        TOPIC_DISTURBANCE: ChannelFilter(self.plant.disturbance_names,
                                                         ranges=setup.ranges)}
        # taken as CDR bytes and decoded directly (nodes/cdr.py)
        self._input_subs = [
            self.create_subscription(JointState, topic, functools.partial(self._on_input, topic),
                                     SIGNAL_QOS, event_callbacks=quiet_subscription_events(),
                                     raw=True)
            for topic in (TOPIC_MANIPULATED, TOPIC_DISTURBANCE)]
        self._match_since: float | None = None     # sim/wall: the wait before tick 0 (match_wait)
        self._match_timer: Timer | None = None
        # lockstep flow control with the harness's recorder (``lockstep.record_window``)
        if self._protocol.window:
            self.create_subscription(
                Time, TOPIC_RECORDED, lambda m: self._protocol.recorded(stamp_to_ns(m)),
                RECORDED_QOS, event_callbacks=quiet_subscription_events())
        self.create_timer(float(values['diagnostics_period']), self._publish_diagnostics,
                          clock=steady_clock())
        self._matched_sent: dict[str, int] | None = None   # in the last /diagnostics
        self._prestart_calls = 0           # sim/wall (the harness waits for them): _on_prestart
        self._prestart_timer = (self.create_timer(0.02, self._on_prestart, clock=steady_clock())
                                if self._protocol.prestart_reports else None)
        self.add_post_set_parameters_callback(self._on_params_set)
        try:            # opcua.endpoint: the plant served over OPC UA too (docs/opcua.md)
            self.opcua = PlantOpcua(str(values['opcua.endpoint']), self.plant.output_names,
                                    self.plant.input_names, setup.ranges, self._protocol.u,
                                    self._protocol.real_time)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self._protocol.start()
        self.get_logger().info(
            f'plant {kind} ({setup.kind.description}): outputs {list(self.plant.output_names)}, inputs '
            f'{list(self.plant.input_names)}, disturbances {list(self.plant.disturbance_names)}; '
            f'{self._protocol.mode} clock, sample_time {self._protocol.ts:g} s')

    # ------------------------------------------------- the host of the protocol
    @property
    def paused(self) -> bool:
        return self._is_paused

    @property
    def real_time_factor(self) -> float:
        return float(self.params.values['real_time_factor'])

    def timer(self, period_s: float, callback: Callable[[], None],
              autostart: bool = True) -> Timer:
        return self.create_timer(period_s, callback, clock=steady_clock(), autostart=autostart)

    def destroy(self, timer: Any) -> None:
        self.destroy_timer(timer)

    def publish_measurement(self, msg: bytes) -> None:
        self.measurement_pub.publish(msg)

    def publish_clock(self, msg: bytes) -> None:
        assert self.clock_pub is not None          # called only where publishes_clock
        self.clock_pub.publish(msg)

    def publish_applied(self, msg: bytes) -> None:
        self.applied_pub.publish(msg)

    def publish_origin(self, origin_ns: int) -> None:
        self.origin_pub.publish(ns_to_stamp(origin_ns))

    def publish_late(self, t_ns: int, names: list[str], values: list[float]) -> None:
        self.late_pub.publish(to_joint_state(t_ns, names, values))

    def measured(self, stamp_ns: int, y: Any) -> None:
        self.opcua.measured(stamp_ns, y)

    def destroy_node(self) -> None:
        if getattr(self, 'opcua', None) is not None:
            self.opcua.stop()
        super().destroy_node()

    def ros_now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def warning(self, text: str) -> None:
        self.get_logger().warning(text)

    # ------------------------------------------------------------- parameters
    def _cross_check(self, values: Mapping[str, Any], changed: frozenset[str]) -> str | None:
        """The whole candidate set as at start-up (node relations, the model's configuration
        and its relations such as dead_time <= max_dead_time) and noise_std: 1 value or one
        per output."""
        protocol = getattr(self, '_protocol', None)        # None at start-up
        refused = protocol.pause_refused(bool(values['lockstep.paused'])) if protocol else None
        if refused:
            return refused
        model = sorted(n for n in changed if n not in _NODE_ONLY
                       and not n.startswith(_NODE_ONLY_PREFIX))
        if protocol and model and not isinstance(self.plant, Configurable):
            return (f'{", ".join(model)}: plant kind {values["plant"]!r} has no live changes '
                    '(its model has no configure()); restart plant_node with the new value')
        try:
            setup = plant_setup(values, getattr(self, '_controller_values', None))
            if hasattr(self, 'plant'):   # at start-up the constructor builds the noise next
                setup.build_noise(len(self.plant.output_names))
        except ConfigError as exc:
            return str(exc)
        return None

    def apply_pending(self) -> None:
        """Accepted parameter changes act from this step on; so do the inputs an OPC UA
        client wrote."""
        self.opcua.take_into(self._protocol)
        pending = self.params.take_pending()
        if not pending:
            return
        model = {k: v for k, v in pending.items()
                 if k not in _NODE_ONLY and not k.startswith(_NODE_ONLY_PREFIX)}
        if model:
            plant = self.plant
            assert isinstance(plant, Configurable)     # else refused (_cross_check)
            try:
                plant.configure(**model)
                self.get_logger().info(f'model change applied at t = {self._protocol.t():g} s: '
                                       f'{model}')
            except ValueError as exc:   # a relation the model checks (e.g. dead_time <= max)
                self.counters['rejected_changes'] += 1
                self.get_logger().warning(f'model change not applied: {exc}')
        if 'noise_std' in pending:
            self.noise.set_std(pending['noise_std'])
        if 'real_time_factor' in pending:
            self._protocol.set_rtf(float(pending['real_time_factor']))

    def _on_params_set(self, parameters: list) -> None:
        """(Un-)pausing acts at once (other changes wait for the next step)."""
        # rclpy may run this before the binding's own post-set callback: read the new value.
        was_paused = self._is_paused
        given = {p.name: p.value for p in parameters if p.name.startswith(ranges.PREFIX)}
        if given:                         # range.* act on the next message
            limits = ranges.ranges_from({**self.params.values, **given},
                                        node_specs.plant_channels(self.params.values['plant']),
                                        self._actuator)
            for flt in self.filters.values():
                flt.ranges = limits
        for p in parameters:
            if p.name == 'lockstep.paused':
                self._is_paused = bool(p.value)
            elif p.name == 'lockstep.resend_period':
                self._protocol.resend_period = float(p.value)
        unpaused = any(p.name == 'lockstep.paused' and not p.value for p in parameters)
        self._protocol.set_paused(self._is_paused, was_paused, unpaused)

    def match_wait(self) -> bool:
        """sim/wall, before tick 0: are readers of the measurement, the time origin, the
        applied input (a controller's take-over waits for it) or /clock, or writers of the
        inputs, in the graph but not yet matched (``messages.unmatched``)?
        Then tick 0 waits (polled every 10 ms) — a tick or origin published before would
        reach them late or never, and the plant does not wait for answers — for at most
        MATCH_WAIT_S, then starts with a warning naming the topics."""
        waiting = unmatched(self, self._start_publishers(), self._input_subs)
        now = time.monotonic()
        if self._match_since is None:
            self._match_since = now
        if waiting and now - self._match_since < MATCH_WAIT_S:
            if self._match_timer is None:
                self._match_timer = self.create_timer(0.01, self._retry_start,
                                                      clock=steady_clock())
            return True
        if waiting:
            self.get_logger().warning(
                f'starting the clock after {MATCH_WAIT_S:g} s with {", ".join(waiting)} not '
                'matched to every endpoint the graph shows (incompatible QoS?): their messages '
                'may come late or not at all')
        if self._match_timer is not None:
            self._match_timer.cancel()         # (maybe in its own callback: not destroyed)
        return False

    def _start_publishers(self) -> list[Any]:
        """Publishers whose readers must be matched before tick 0 (``match_wait``)."""
        return [p for p in (self.measurement_pub, self.origin_pub, self.applied_pub,
                            self.clock_pub) if p is not None]

    def _matched(self) -> dict[str, int]:
        """``matched_readers.<topic>``: readers the middleware has matched to the writer of
        each ``_start_publishers`` topic; ``matched_writers.<topic>``: writers matched to each
        input. In /diagnostics: the harness starts the clock once these reach the endpoints
        its own graph shows (the plant's graph can miss a node for seconds)."""
        items = {f'matched_readers.{p.topic_name}': p.get_subscription_count()
                 for p in self._start_publishers()}
        items.update({f'matched_writers.{s.topic_name}': s.get_publisher_count()
                      for s in self._input_subs})
        return items

    def _on_prestart(self) -> None:
        """Before tick 0 (every 20 ms): /diagnostics at once when a matched count changed,
        else every 0.1 s (a reader that joined after the change need not wait for the
        ``diagnostics_period``)."""
        if self._protocol.tick_msgs is not None or self._protocol.announced:
            if self._prestart_timer is not None:   # (it calls this: never None here)
                self._prestart_timer.cancel()  # (cancelled, not destroyed, in its own callback)
            return
        self._prestart_calls += 1
        if self._matched() != self._matched_sent or self._prestart_calls % 5 == 0:
            self._publish_diagnostics()

    def _retry_start(self) -> None:
        if self._protocol.tick_msgs is None and not self._is_paused:
            self._protocol.start_clock()

    # --------------------------------------------------------------- inputs
    def _on_input(self, topic: str, msg: bytes) -> None:
        """An input message (CDR bytes of a JointState); one stamped more than
        ``max_future_stamp`` ahead of this plant's now is refused (``rejected_future``)."""
        flt = self.filters[topic]
        t_ns, names, accepted, new_reasons = flt.accept(topic, msg)
        if t_ns is not None and not self._future.admit(topic, t_ns, self._protocol.now_ns(),
                                                       time.monotonic_ns()):
            new_reasons += self._future.take_report()
            t_ns = None
        else:
            new_reasons += self._future.take_report()
        for reason in new_reasons:
            self.get_logger().warning(reason + ' (logged at most once per diagnostics period)')
        if t_ns is None:
            return                      # malformed or refused: no arrival, nothing taken
        self._protocol.input(topic, t_ns, names, accepted, flt.known)

    # ----------------------------------------------------------- diagnostics
    def _log_stall(self, stall: str) -> None:
        """A stall is logged once when it starts (WARN, the diagnostics' text) and once when
        it ends; its kind is its text without the seconds, which grow."""
        kind = ' '.join(w for w in stall.split() if not any(c.isdigit() for c in w))
        if kind and kind != self._stall_logged:
            self.get_logger().warning(stall)
        elif not kind and self._stall_logged:
            self.get_logger().info('inputs arrive: the loop moves')
        self._stall_logged = kind

    def _publish_diagnostics(self) -> None:
        # the filters count per message; the totals are taken here, off the hot path
        for key, attr in (('ignored_inputs', 'ignored'), ('out_of_range_inputs', 'out_of_range'),
                          ('unknown_channels', 'unknown'), ('oversized_inputs', 'oversized')):
            self.counters[key] = sum(getattr(f, attr) for f in self.filters.values())
        self.counters['rejected_future'] = self._future.refused
        for flt in self.filters.values():
            flt.rearm()                 # each kind of reason logged again at most once a period
        self._future.rearm_reports()
        self._protocol.past_logged.clear()
        status = DiagnosticStatus(name='plant', hardware_id=str(self.params.values.get('plant', '')))
        model = dict(self.plant.status)
        problems = [f'{self.counters[key]} {text}' for key, text in (
            ('ignored_inputs', 'ignored inputs'),
            ('rejected_future', 'inputs stamped in the future refused'),
            ('rejected_past', 'inputs stamped in the past refused')) if self.counters[key]]
        if model.get('clipped_flows'):
            problems.append(f"{model['clipped_flows']} clipped flows")
        if model.get('overflow'):
            problems.append('overflowing')
        behind = self._protocol.pace_report()
        if behind:
            problems.append(behind)
        stall = self._protocol.stall_report()
        self._log_stall(stall)
        if stall:
            problems.append(stall)
        status.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
        status.message = ', '.join(problems) or 'ok'
        items = {'clock_mode': self._protocol.mode, 'sim_time': f'{self._protocol.t():.9g}',
                 'time_origin_ns': self._protocol.stamp_offset_ns, **self.counters}
        self._matched_sent = self._matched()
        items.update(paused=self._is_paused, **self.opcua.counters(), **self._matched_sent,
                     step_time_ms=f'{self._protocol.step_ms:.4g}')
        waiting = self._protocol.waiting_for()
        if waiting is not None:
            items['waiting_for'] = waiting
        for name, value in model.items():
            items[f'model.{name}'] = value
        for topic, flt in self.filters.items():
            items[f'ignored.{topic}'] = flt.ignored
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in items.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args: list[str] | None = None) -> int:
    """Console entry point plant_node; exit 2 with a one-line reason on bad parameters."""
    return run_node_main('plant_node', PlantNode, args)


if __name__ == '__main__':
    sys.exit(main())
