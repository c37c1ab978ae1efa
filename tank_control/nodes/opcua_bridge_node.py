"""opcua_bridge_node (node ``opcua_bridge``): an OPC UA server's variables as the loop's plant.

Takes plant_node's place on the graph in wall mode: announces ``time_origin`` (latched),
publishes ``measurement`` (``sensor_msgs/JointState``, stamped with the server's
SourceTimestamp), subscribes ``manipulated`` and writes it to the server; ``/diagnostics``
(ERROR while the server is not connected). The OPC UA side is ``tank_control/opcua/bridge.py``
(its own asyncio thread); this node only adapts. docs/opcua.md.

Time origin: announced once, before the first measurement published, on the server's sample
grid shifted by half a sample time (``origin = s0 - ts/2 + m·ts``, at least ``ORIGIN_NOTICE_S``
ahead): the controller's instant ``floor((stamp - origin) / sample_time)`` of each server
sample is then its own even with the server's jitter of up to half a sample time.
"""
from __future__ import annotations

import dataclasses
import logging
import sys
import threading
import time
import uuid
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import JointState

from tank_control.core import params_file, ranges
from tank_control.core.interfaces import to_ns
from tank_control.core.params import ConfigError
from tank_control.core.stamps import FutureStamps, future_tolerance_ns
from tank_control.nodes.cdr import JointStateCdr
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.messages import (MATCH_WAIT_S, ORIGIN_QOS, SIGNAL_QOS, TOPIC_DIAGNOSTICS,
                                         TOPIC_MANIPULATED, TOPIC_MEASUREMENT, TOPIC_TIME_ORIGIN,
                                         ns_to_stamp, parse_signal, quiet_publisher_events,
                                         quiet_subscription_events, unmatched)
from tank_control.nodes.params import ParameterBinding, ParameterError
from tank_control.nodes.runtime import main as run_node_main
from tank_control.opcua import config as opcua_config
from tank_control.opcua.bridge import Bridge, Sample

NODE_NAME = 'opcua_bridge'
#: the time origin is announced at least this long before the first measurement published
#: (as plant_node does in wall mode: the reference's instant 0 comes first) [s]
ORIGIN_NOTICE_S = 0.2


def _start_values(node: Node) -> dict[str, Any]:
    """The channel lists given at start-up (params file / command line), flat."""
    overrides = getattr(node, '_parameter_overrides', {})   # rclpy has no public getter
    return {name: (list(p.value) if not isinstance(p.value, (str, bytes))
                   and hasattr(p.value, '__len__') else p.value)
            for name, p in overrides.items() if name.endswith('.channels')}


def _controller_values(name: str, argv: list[str] | None = None) -> dict[str, Any] | None:
    """The controller ``name``'s values from this node's ``--params-file`` files."""
    return params_file.node_values_on_command_line(name, sys.argv if argv is None else argv)


class OpcUaBridgeNode(Node):
    """The ROS side of the OPC UA bridge (module doc)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, allow_undeclared_parameters=True, **kwargs)
        start = _start_values(self)
        controller = _controller_values(f'{self.get_namespace().rstrip("/")}/controller')
        self._limits_from = ('the controller\'s u limits in the params file' if controller
                             else '')
        actuator = opcua_config.controller_limits(controller)
        self._actuator = actuator
        try:
            specs = opcua_config.specs(start, actuator)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.params = ParameterBinding(self, specs, cross_check=self._cross_check)
        try:
            settings = opcua_config.settings_from(self.params.values, actuator)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.settings = settings
        self.ts_ns = to_ns(settings.node.sample_time)
        self.names = tuple(settings.measurement)
        given = getattr(self, '_parameter_overrides', {})
        for ch in settings.manipulated:
            if ch not in actuator and ranges.name_of(ch) not in given:
                lo, hi = settings.limits.bounds[ch]
                self.get_logger().warning(
                    f'manipulated.{ch}: no limits known (no controller section in the params '
                    f'file, no {ranges.name_of(ch)}): writes limited to [{lo:g}, {hi:g}] only; '
                    f'set {ranges.name_of(ch)} to the actuator\'s range')
        self.add_post_set_parameters_callback(self._on_params_set)
        self._session = uuid.uuid4().hex[:16]
        self._lock = threading.Lock()
        self._origin_ns: int | None = None
        self._first_sample_at: float | None = None
        self.counters = {'before_origin': 0, 'ignored_inputs': 0, 'out_of_order_inputs': 0,
                         'rejected_future': 0}
        # stamps more than 5 sample times ahead of this host's clock are refused (both ways):
        # one stray stamp would otherwise set the time origin or the order of writes
        self._future = FutureStamps(future_tolerance_ns(None, settings.node.sample_time))
        self._last_u_stamp: int | None = None
        self._logged: set[str] = set()
        self.measurement_pub = self.create_publisher(JointState, TOPIC_MEASUREMENT, SIGNAL_QOS,
                                                     event_callbacks=quiet_publisher_events())
        # the hot path as CDR bytes, encoded and decoded directly (nodes/cdr.py)
        self._measurement_cdr = JointStateCdr(self.names)
        self.origin_pub = self.create_publisher(Time, TOPIC_TIME_ORIGIN, ORIGIN_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._u_sub = self.create_subscription(JointState, TOPIC_MANIPULATED, self._on_manipulated,
                                               SIGNAL_QOS, raw=True,
                                               event_callbacks=quiet_subscription_events())
        # asyncua logs every lost connection with a traceback: the bridge reports them itself
        logging.getLogger('asyncua').setLevel(logging.CRITICAL)
        self.bridge = Bridge(settings, self._on_sample, self._log)
        self.bridge.start()
        wait = 2 * settings.node.request_timeout + 1.0
        self.bridge.wait_first_attempt(wait)
        if self.bridge.state == 'node_fault':
            self.bridge.stop()
            raise ParameterError(self.bridge.problem)
        self.create_timer(settings.node.diagnostics_period,
                          self._publish_diagnostics, clock=steady_clock())
        self.get_logger().info(
            f'OPC UA bridge to {settings.node.endpoint}: measurement {list(settings.measurement)}'
            f', manipulated {list(settings.manipulated)}, sample_time '
            f'{settings.node.sample_time:g} s; writes limited to '
            + (', '.join(f'{ch} [{lo:g}, {hi:g}]' for ch, (lo, hi) in
                         settings.limits.bounds.items()) or 'nothing')
            + (f' ({self._limits_from})' if self._limits_from else ''))

    def _cross_check(self, values: Any, changed: frozenset[str]) -> str | None:
        try:
            opcua_config.settings_from(values, self._actuator)
        except ConfigError as exc:
            return str(exc)
        return None

    def _on_params_set(self, parameters: list) -> None:
        """``range.*`` act on the next write."""
        given = {p.name: p.value for p in parameters if p.name.startswith(ranges.PREFIX)}
        if given:
            limits = ranges.ranges_from({**self.params.values, **given},
                                        list(self.settings.manipulated), self._actuator)
            self.settings = dataclasses.replace(self.settings, limits=limits)
            self.bridge.settings = self.settings

    def destroy_node(self) -> None:
        bridge = getattr(self, 'bridge', None)
        if bridge is not None:
            bridge.stop()
        super().destroy_node()

    def _log(self, level: str, text: str) -> None:
        # one call site per severity: rclpy refuses another severity at the same site
        logger = self.get_logger()
        if level == 'error':
            logger.error(text)
        elif level == 'warning':
            logger.warning(text)
        else:
            logger.info(text)

    def _log_once(self, key: str, text: str) -> None:
        if key not in self._logged:
            self._logged.add(key)
            self.get_logger().warning(text + ' (logged at most once per diagnostics period)')

    # ----------------------------------------------------------- measurements
    def _on_sample(self, sample: Sample) -> None:
        """A server sample (the bridge's thread): the time origin first, then published."""
        with self._lock:
            if not self._admit(TOPIC_MEASUREMENT, sample.stamp_ns):
                return
            if self._origin_ns is None and not self._announce(sample.stamp_ns):
                self.counters['before_origin'] += 1
                return
            assert self._origin_ns is not None
            if sample.stamp_ns < self._origin_ns:
                self.counters['before_origin'] += 1
                return
        self.measurement_pub.publish(self._measurement_cdr.encode_ns(
            sample.stamp_ns, [sample.values[n] for n in self.names]))

    def _announce(self, stamp_ns: int) -> bool:
        """The time origin, once the readers the graph shows are matched (at most
        MATCH_WAIT_S): on the server's grid shifted by half a sample time (module doc)."""
        now = time.monotonic()
        if self._first_sample_at is None:
            self._first_sample_at = now
        waiting = unmatched(self, [self.measurement_pub, self.origin_pub], [])
        if waiting and now - self._first_sample_at < MATCH_WAIT_S:
            return False
        base = stamp_ns - self.ts_ns // 2
        notice = time.time_ns() + to_ns(ORIGIN_NOTICE_S) - base
        periods = max(0, -(-notice // self.ts_ns))
        self._origin_ns = base + periods * self.ts_ns
        self.origin_pub.publish(ns_to_stamp(self._origin_ns))
        self.get_logger().info(f'time origin {self._origin_ns} ns (the server\'s sample grid '
                               'shifted by half a sample time)')
        return True

    # ------------------------------------------------------------ manipulated
    def _on_manipulated(self, msg: bytes) -> None:
        try:
            stamp, _, names, values = parse_signal(msg)
        except ValueError as exc:
            self.counters['ignored_inputs'] += 1
            self._log_once('malformed', f'{TOPIC_MANIPULATED}: malformed message ignored ({exc})')
            return
        if not self._admit(TOPIC_MANIPULATED, stamp):
            return
        if self._last_u_stamp is not None and stamp < self._last_u_stamp:
            if not self._future.back_on_clock(TOPIC_MANIPULATED, self._last_u_stamp, stamp,
                                              time.time_ns()):
                self.counters['out_of_order_inputs'] += 1
                self._log_once('order', f'{TOPIC_MANIPULATED}: a message older than the last '
                               'one ignored')
                return
            self.bridge.forget_instants()        # the stream's clock went back (a restart)
        self._last_u_stamp = stamp
        origin = self._origin_ns or 0
        for reason in self.bridge.write(dict(zip(names, values)),
                                        (stamp - origin) // self.ts_ns):
            # one key for every unknown name: a flood of names is one line per period
            key = 'unknown' if reason.startswith('unknown') else reason.split(':')[0]
            self._log_once(key, f'{TOPIC_MANIPULATED}: {reason}')

    def _admit(self, topic: str, stamp_ns: int) -> bool:
        """False (counted, reported once per diagnostics period) for a stamp further ahead of
        this host's clock than the tolerance (core/stamps.FutureStamps, with its clock-step
        recovery)."""
        if self._future.admit(topic, stamp_ns, time.time_ns(), time.monotonic_ns()):
            return True
        self.counters['rejected_future'] += 1
        for line in self._future.take_report():
            self.get_logger().warning(line)
        return False

    # ------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self) -> None:
        bridge = self.bridge
        self._logged.clear()
        self._future.rearm_reports()
        bridge.rearm()
        counters = {**bridge.counters, **self.counters}
        problems = []
        if bridge.state != 'connected':
            level = DiagnosticStatus.ERROR
            problems.append(f'not connected to {self.settings.node.endpoint}: '
                            f'{bridge.problem or "connecting"}')
        else:
            level = DiagnosticStatus.OK
        if counters['receive_stamps']:
            problems.append(f"{counters['receive_stamps']} values without SourceTimestamp "
                            'stamped with the receive time')
        for key, text in (('bad_status', 'samples with a Bad/Uncertain status or no finite '
                                         'value not published'),
                          ('refused_writes', 'writes refused by the server'),
                          ('refused_limits', 'manipulated values outside range.* not written'),
                          ('ignored_inputs', 'malformed manipulated messages'),
                          ('rejected_future', 'messages stamped ahead of this host\'s clock '
                           'refused')):
            if counters[key]:
                problems.append(f'{counters[key]} {text}')
        if problems and level == DiagnosticStatus.OK:
            level = DiagnosticStatus.WARN
        status = DiagnosticStatus(name=NODE_NAME, hardware_id=self.settings.node.endpoint,
                                  level=level, message=', '.join(problems) or 'ok')
        items: dict[str, Any] = {
            'state': bridge.state, 'endpoint': self.settings.node.endpoint,
            'security': self.settings.node.policy + (
                f' {self.settings.node.mode}' if self.settings.node.policy != 'None' else ''),
            'stamps': self.settings.node.stamp, 'time_origin_ns': self._origin_ns or 0,
            **counters}
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in items.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args: list[str] | None = None) -> int:
    """Console entry point opcua_bridge_node; exit 2 with a one-line reason on bad parameters
    or a node id the server does not serve as a numeric variable."""
    return run_node_main('opcua_bridge_node', OpcUaBridgeNode, args)


if __name__ == '__main__':
    sys.exit(main())
