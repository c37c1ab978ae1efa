"""reference_node: publishes the setpoint and disturbance schedules of ``core/reference.py``.

Publishes ``setpoint`` and ``disturbance`` (``sensor_msgs/JointState`` by channel name): in
``wall`` mode every ``sample_time`` of plant time from the plant's ``time_origin`` on, otherwise
one idempotent answer per ``/clock`` tick (in ``lockstep`` also one tick ahead). Parameter
layout, runtime overrides and timing: docs/nodes.md ("reference_node"). Times in s.
"""
from __future__ import annotations

import copy
import sys
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.core.interfaces import seconds, to_ns
from tank_control.core.node_specs import ReferenceNode as ReferenceNodeConfig
from tank_control.core.params import ConfigError, specs_of
from tank_control.core.reference import Reference, channel_lists, channel_specs, split_param_name
from tank_control.core.scenario import reference_setup
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.messages import (CLOCK_QOS, ORIGIN_QOS, SIGNAL_QOS, TOPIC_CLOCK,
                                         TOPIC_DIAGNOSTICS, TOPIC_DISTURBANCE, TOPIC_SETPOINT,
                                         TOPIC_TIME_ORIGIN,
                                         quiet_publisher_events, quiet_subscription_events,
                                         stamp_to_ns, to_joint_state)
from tank_control.nodes.params import ParameterBinding, ParameterError
from tank_control.nodes.runtime import main as run_node_main


def _channel_values(node: Node) -> dict[str, Any]:
    """The node's start-up channel values from the params file / command line (flat)."""
    overrides = getattr(node, '_parameter_overrides', {})   # rclpy has no public getter
    return {name: (list(p.value) if not isinstance(p.value, (str, bytes))
                   and hasattr(p.value, '__len__') else p.value)
            for name, p in overrides.items() if name.split('.')[0] in ('setpoint', 'disturbance')}


class ReferenceNode(Node):
    """Setpoint/disturbance publisher around a core ``Reference``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('reference', allow_undeclared_parameters=True, **kwargs)
        try:
            reference = reference_setup(_channel_values(self)).reference
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.reference: Reference = reference
        self.params = ParameterBinding(self, specs_of(ReferenceNodeConfig) + channel_specs(reference),
                                       cross_check=self._cross_check)
        self.setpoint_pub = self.create_publisher(JointState, TOPIC_SETPOINT, SIGNAL_QOS,
                                                  event_callbacks=quiet_publisher_events())
        self.disturbance_pub = self.create_publisher(JointState, TOPIC_DISTURBANCE, SIGNAL_QOS,
                                                     event_callbacks=quiet_publisher_events())
        self._last_t = 0.0
        self._answered: dict[int, tuple[JointState, JointState]] = {}
        self._last_clock: int | None = None
        # Only in an explicit lockstep: in sim the others use the latest message, which
        # must be the current tick's (use_sim_time alone does not tell sim from lockstep).
        self._anticipate = (bool(self.params.values['lockstep.anticipate'])
                            and self.params.values['clock_mode'] == 'lockstep')
        self.published = 0
        self.use_sim_time = (bool(self.get_parameter('use_sim_time').value)
                             or self.params.values['clock_mode'] != 'wall')
        if self.use_sim_time:
            self.create_subscription(Clock, TOPIC_CLOCK, self._on_clock, CLOCK_QOS,
                                     event_callbacks=quiet_subscription_events())
            # a plant on the wall clock latches a non-zero origin and sends no /clock
            self.create_subscription(Time, TOPIC_TIME_ORIGIN, self._check_origin, ORIGIN_QOS)
            self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
            self._conflict = ''
        else:
            period = float(self.params.values['sample_time'])
            self._origin_ns: int | None = None
            self._last_t_ns = -1
            self._timer = self.create_timer(period, self._on_timer, clock=steady_clock(),
                                            autostart=False)
            self.create_subscription(Time, TOPIC_TIME_ORIGIN, self._on_origin, ORIGIN_QOS)
            self.add_post_set_parameters_callback(self._after_set)
        sp, dist = channel_lists(self.params.values)
        self.get_logger().info(
            f'reference: setpoints {sp or "none"}, disturbances {dist or "none"}, '
            + ('answering /clock ticks' if self.use_sim_time else
               f'every {period:g} s of plant time (waiting for the plant\'s {TOPIC_TIME_ORIGIN})'))

    # ------------------------------------------------------------- parameters
    def _cross_check(self, values: dict[str, Any], changed: frozenset[str]) -> str | None:
        """The change must leave every schedule valid: it is tried on a copy of the
        running reference (which includes earlier overrides), so nothing accepted
        here can be refused when it is applied."""
        params = getattr(self, 'params', None)
        if params is None:
            return None          # start-up: reference_from_params has checked the file
        current = params.values
        trial = copy.deepcopy(self.reference)
        by_channel: dict[tuple[str, str], dict[str, Any]] = {}
        for name, value in values.items():
            parts = split_param_name(name)
            if parts and current.get(name) != value:
                by_channel.setdefault(parts[:2], {})[parts[2]] = value
        for (kind, ch), changes in by_channel.items():
            reason = trial.update(kind, ch, changes, self._last_t)
            if reason:
                return reason
        return None

    def _apply_pending(self, t: float) -> None:
        """Accepted parameter changes take effect at instant ``t`` [s]."""
        pending = self.params.take_pending()   # (wall: a new sample_time acts at re-arming)
        by_channel: dict[tuple[str, str], dict[str, Any]] = {}
        for name, value in pending.items():
            parts = split_param_name(name)
            if parts:
                by_channel.setdefault(parts[:2], {})[parts[2]] = value
        for (kind, ch), changes in by_channel.items():
            reason = self.reference.update(kind, ch, changes, t)
            if reason:   # accepted as parameters but inconsistent with the running schedule
                self.get_logger().warning(f'change of {kind}.{ch} not applied: {reason}')
            else:
                self.get_logger().info(f'{kind}.{ch}: {changes} from t = {t:g} s')

    # ---------------------------------------------------------------- publish
    def _publish(self, stamp_ns: int, t: float) -> None:
        self._last_t = max(self._last_t, t)
        self._apply_pending(t)
        ref = self.reference
        sp = to_joint_state(stamp_ns, ref.setpoint_names, ref.setpoints(t))
        dist = to_joint_state(stamp_ns, ref.disturbance_names, ref.disturbances(t))
        self._answered[stamp_ns] = (sp, dist)
        self.setpoint_pub.publish(sp)
        self.disturbance_pub.publish(dist)
        self.published += 1

    def _on_clock(self, msg: Clock) -> None:
        """Answer tick t_k once (idempotent: a re-sent /clock gets the same messages);
        with ``lockstep.anticipate`` also answer the next tick ahead."""
        t_ns = stamp_to_ns(msg.clock)
        if t_ns == 0 and self._last_clock:  # the plant (re)started: a new run
            self.get_logger().info('/clock restarted at 0: answering a new run')
            self._answered.clear()
            self._last_clock = None
        if self._last_clock is not None and t_ns < self._last_clock:
            return                        # a stale duplicate of an earlier tick
        cached = self._answered.get(t_ns)
        if t_ns == self._last_clock and cached is not None:   # the plant re-sent tick k
            for pub, answer in zip((self.setpoint_pub, self.disturbance_pub), cached):
                pub.publish(answer)
            return
        previous, self._last_clock = self._last_clock, t_ns
        for stamp in [s for s in self._answered if s < t_ns]:
            del self._answered[stamp]
        if cached is None:
            self._publish(t_ns, seconds(t_ns))
        if self._anticipate and previous is not None and t_ns > previous:
            ahead = 2 * t_ns - previous   # the plant's ticks are evenly spaced
            if ahead not in self._answered:
                self._publish(ahead, seconds(ahead))

    def _check_origin(self, msg: Time) -> None:
        """/clock mode: a non-zero time origin is a wall-clock plant, whose ticks this node
        would wait for forever: logged, and /diagnostics ERROR with the remedy every second
        from then on."""
        origin = stamp_to_ns(msg)
        if origin == 0 or self._conflict:
            return
        self._conflict = (f'the plant runs on the wall clock (time_origin {origin} ns) but this '
                          f'node answers /clock ticks (clock_mode '
                          f'{self.params.values["clock_mode"]}, use_sim_time '
                          f'{self.get_parameter("use_sim_time").value}): it will never publish; '
                          'start it with clock_mode wall and use_sim_time false')
        self.get_logger().error(self._conflict)
        self._report_conflict()
        self.create_timer(1.0, self._report_conflict, clock=steady_clock())

    def _report_conflict(self) -> None:
        status = DiagnosticStatus(level=DiagnosticStatus.ERROR, name='reference',
                                  message=f'not publishing: {self._conflict}',
                                  hardware_id='tank_control')
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(array)

    def _on_origin(self, msg: Time) -> None:
        """wall: the plant's time origin; (re)start the grid of instants from it."""
        origin = stamp_to_ns(msg)
        if origin == self._origin_ns:
            return
        if self._origin_ns is not None:
            self.get_logger().info('new plant time origin (the plant restarted): schedule '
                                   'restarts at 0')
        self._origin_ns, self._last_t_ns = origin, -1
        self._on_timer()

    def _after_set(self, parameters: list[Parameter]) -> None:
        """wall: a new ``sample_time`` re-arms the timer on the new grid at once (otherwise
        the wait for the next instant of the old grid, up to a whole old period, runs out
        first). rclpy calls post-set callbacks last-added first, so this runs before
        ParameterBinding stores the value: the period is taken from the request."""
        for param in parameters:
            if param.name == 'sample_time' and self._origin_ns is not None:
                self._on_timer(to_ns(float(param.value)))

    def _on_timer(self, period_ns: int | None = None) -> None:
        """wall: publish the latest instant reached (if not yet), re-arm for the next."""
        self._timer.cancel()
        if period_ns is None:
            period_ns = to_ns(float(self.params.values['sample_time']))
        elapsed = self.get_clock().now().nanoseconds - self._origin_ns
        if elapsed < 0:                  # before the plant's tick 0: wait for instant 0
            self._timer.timer_period_ns = -elapsed
            self._timer.reset()
            return
        t_ns = elapsed // period_ns * period_ns      # the latest instant reached
        if t_ns > self._last_t_ns:
            self._last_t_ns = t_ns
            self._publish(self._origin_ns + t_ns, seconds(t_ns))
        self._timer.timer_period_ns = t_ns + period_ns - elapsed
        self._timer.reset()


def main(args: list[str] | None = None) -> int:
    """Console entry point reference_node; exit 2 with a one-line reason on bad parameters."""
    return run_node_main('reference_node', ReferenceNode, args)


if __name__ == '__main__':
    sys.exit(main())
