"""signal_bridge_node (node ``signal_bridge``): real sensors and actuators as the loop's plant.

Per channel between the loop's signal topics (``measurement``, ``manipulated``: JointState
channels) and a driver's ``std_msgs/Float64`` or stamped ``sensor_msgs`` scalar topics; the
mapping and its checks are ``core/signal_bridge.py`` (no rclpy), this node only adapts:
subscriptions and publishers per channel, the latched ``time_origin`` (wall clock) before the
first measurement, ``/diagnostics`` with the counters, the refusals logged at most once per
diagnostics period. docs/signal_bridge.md.
"""
from __future__ import annotations

import sys
import time
from collections.abc import Callable
from importlib import import_module
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from tank_control.core import params_file, ranges
from tank_control.core import signal_bridge as core_bridge
from tank_control.core.params import ConfigError
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.messages import (MATCH_WAIT_S, ORIGIN_QOS, SIGNAL_QOS, TOPIC_DIAGNOSTICS,
                                         TOPIC_MANIPULATED, TOPIC_MEASUREMENT, TOPIC_TIME_ORIGIN,
                                         ns_to_stamp, parse_signal, stamp_to_ns, to_joint_state,
                                         unmatched)
from tank_control.nodes.params import ParameterBinding, ParameterError
from tank_control.nodes.runtime import main as run_node_main

NODE_NAME = 'signal_bridge'
#: a driver's topics: best-effort readers match reliable and best-effort (sensor data) writers
DRIVER_IN_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                           reliability=ReliabilityPolicy.BEST_EFFORT)
#: commands to a driver: reliable (a best-effort reader matches it too)
DRIVER_OUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                            reliability=ReliabilityPolicy.RELIABLE)


def message_class(kind: str) -> type:
    """The message class of ``<direction>.<ch>.type`` ``kind``."""
    package, _, name = core_bridge.TYPES[kind].ros_type.split('/')
    return getattr(import_module(f'{package}.msg'), name)


def _start_values(node: Node) -> dict[str, Any]:
    """The channel lists given at start-up (params file / command line), flat."""
    overrides = getattr(node, '_parameter_overrides', {})   # rclpy has no public getter
    return {name: (list(p.value) if not isinstance(p.value, (str, bytes))
                   and hasattr(p.value, '__len__') else p.value)
            for name, p in overrides.items() if name.endswith('.channels')}


def _actuator(namespace: str) -> dict[str, tuple[float, float]]:
    """The controller's output limits from this node's ``--params-file`` files ({} without)."""
    from tank_control.core.node_specs import controller_input_limits
    values = params_file.node_values_on_command_line(f'{namespace.rstrip("/")}/controller',
                                                     sys.argv)
    return {ch: (float(lo), float(hi)) for ch, (lo, hi) in
            controller_input_limits(values).items() if -1e308 < lo < hi < 1e308}


class SignalBridgeNode(Node):
    """The ROS side of the signal bridge (module doc)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, allow_undeclared_parameters=True, **kwargs)
        actuator = _actuator(self.get_namespace())
        self._actuator = actuator
        try:
            specs = core_bridge.specs(_start_values(self), actuator)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.params = ParameterBinding(self, specs, cross_check=self._cross_check)
        try:
            settings = core_bridge.settings_from(self.params.values, actuator)
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.settings = settings
        self.mapping = core_bridge.SignalMapping(settings)
        self.add_post_set_parameters_callback(self._on_params_set)
        self.measurement_pub = self.create_publisher(JointState, TOPIC_MEASUREMENT, SIGNAL_QOS)
        self.origin_pub = (self.create_publisher(Time, TOPIC_TIME_ORIGIN, ORIGIN_QOS)
                           if settings.node.announce_origin and settings.measurement else None)
        self.diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self._first_value_at: float | None = None
        self._drivers: dict[str, tuple[core_bridge.Channel, Any]] = {}
        for ch in settings.measurement:
            self.create_subscription(message_class(ch.type), ch.topic, self._driver_callback(ch),
                                     DRIVER_IN_QOS)
        for ch in settings.manipulated:
            self._drivers[ch.name] = (ch, self.create_publisher(message_class(ch.type), ch.topic,
                                                                DRIVER_OUT_QOS))
        if settings.manipulated:
            self.create_subscription(JointState, TOPIC_MANIPULATED, self._on_manipulated,
                                     SIGNAL_QOS)
        self.create_timer(settings.node.diagnostics_period, self._publish_diagnostics,
                          clock=steady_clock())
        if settings.node.publish == 'sample' and settings.measurement:
            # checks a quarter period: each instant is published once, at most ts/4 after it
            self.create_timer(settings.node.sample_time / 4, self._sample)
        self.get_logger().info(
            'signal bridge: measurement '
            + (', '.join(f'{c.name} <- {c.topic} ({c.type})' for c in settings.measurement)
               or 'none')
            + '; manipulated '
            + (', '.join(f'{c.name} -> {c.topic} ({c.type}, range '
                         f'[{settings.limits.bounds[c.name][0]:g}, '
                         f'{settings.limits.bounds[c.name][1]:g}])'
                         for c in settings.manipulated) or 'none'))

    def _cross_check(self, values: Any, changed: frozenset[str]) -> str | None:
        try:
            core_bridge.settings_from(values, self._actuator)
        except ConfigError as exc:
            return str(exc)
        return None

    def _on_params_set(self, parameters: list) -> None:
        """``range.*`` act on the next write."""
        given = {p.name: p.value for p in parameters if p.name.startswith(ranges.PREFIX)}
        if given:
            self.mapping.settings = core_bridge.settings_from(
                {**self.params.values, **given}, self._actuator)

    def _driver_callback(self, channel: core_bridge.Channel) -> Callable[[Any], None]:
        return lambda msg: self._on_driver(channel, msg)

    def _on_driver(self, channel: core_bridge.Channel, msg: Any) -> None:
        """A driver's value: to ``measurement``, stamped with its stamp or the wall clock."""
        if self._origin_held():
            self.mapping.held_before_origin()
            return
        stamp = stamp_to_ns(msg.header.stamp) if channel.scalar.stamped else None
        try:
            value = float(getattr(msg, channel.scalar.field))
        except (TypeError, ValueError):
            value = float('nan')
        out = self.mapping.measurement(channel.name, value, stamp,
                                       self.get_clock().now().nanoseconds, time.monotonic_ns())
        if self.mapping.new_origin is not None and self.origin_pub is not None:
            self.origin_pub.publish(ns_to_stamp(self.mapping.new_origin))
            self.get_logger().info(f'time origin {self.mapping.new_origin} ns (the first '
                                   'measurement\'s grid shifted by half a sample time)')
            self.mapping.new_origin = None
        if out is not None:
            self.measurement_pub.publish(to_joint_state(out[0], list(out[1]),
                                                        list(out[1].values())))
        self._log_reasons()

    def _sample(self) -> None:
        """``measurement.publish: sample``: the message of the instant reached, if any."""
        out = self.mapping.sample(self.get_clock().now().nanoseconds)
        if out is not None:
            self.measurement_pub.publish(to_joint_state(out[0], list(out[1]),
                                                        list(out[1].values())))
        self._log_reasons()

    def _origin_held(self) -> bool:
        """Before the time origin is announced: True while a reader of ``measurement`` or
        ``time_origin`` that the graph shows is not matched yet, at most ``MATCH_WAIT_S`` from
        the first driver value (a latched origin published in between reached a reference that
        had started first only seconds later, or in 2 of 13 test runs never: it then never
        published a setpoint)."""
        if self.origin_pub is None or self.mapping.origin_ns is not None:
            return False
        now = time.monotonic()
        if self._first_value_at is None:
            self._first_value_at = now
        return (bool(unmatched(self, [self.measurement_pub, self.origin_pub], []))
                and now - self._first_value_at < MATCH_WAIT_S)

    def _on_manipulated(self, msg: JointState) -> None:
        try:
            stamp, _, names, values = parse_signal(msg)
        except ValueError as exc:
            self.mapping.malformed(str(exc))
            self._log_reasons()
            return
        for name, value, stamp_ns in self.mapping.manipulated(stamp, names, values):
            channel, pub = self._drivers[name]
            out = message_class(channel.type)()
            setattr(out, channel.scalar.field, value)
            if channel.scalar.stamped:
                out.header.stamp = ns_to_stamp(stamp_ns)
            pub.publish(out)
        self._log_reasons()

    def _log_reasons(self) -> None:
        for text in self.mapping.take_reasons():
            self.get_logger().warning(text + ' (logged at most once per diagnostics period)')

    def _publish_diagnostics(self) -> None:
        mapping = self.mapping
        mapping.rearm()
        level, message = mapping.status()
        status = DiagnosticStatus(name=NODE_NAME, hardware_id='',
                                  level=DiagnosticStatus.WARN if level == 'warn'
                                  else DiagnosticStatus.OK, message=message)
        items = {'time_origin_ns': mapping.origin_ns or 0, **mapping.counters}
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in items.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args: list[str] | None = None) -> int:
    """Console entry point signal_bridge_node; exit 2 with a one-line reason on bad
    parameters."""
    return run_node_main('signal_bridge_node', SignalBridgeNode, args)


if __name__ == '__main__':
    sys.exit(main())
