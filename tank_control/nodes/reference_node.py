"""reference_node: publishes the setpoint and disturbance schedules of ``core/reference.py``.

Publishes ``setpoint`` and ``disturbance`` (``sensor_msgs/JointState`` by channel name): in
``wall`` mode every ``sample_time`` of plant time from the plant's ``time_origin`` on, in ``sim``
one idempotent answer per ``/clock`` tick, in ``lockstep`` the schedules ``lockstep.lookahead``
ticks ahead under zero-order hold (a message per change, ``protocol.reference.HeldStream``;
the clock protocol is ``nodes/protocol/reference.py``, picked once). The channel
parameters always equal the schedules it runs: a change (an override ``value``, new limits) is
written back to ``times``/``values``, and several parameters set in one call (``ros2 param
load``) are one atomic change. Parameter layout, runtime overrides and timing: docs/nodes.md
("reference_node"). Times in s.
"""
from __future__ import annotations

import copy
import sys
from collections.abc import Iterable, Mapping
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.core.interfaces import to_ns
from tank_control.core.node_specs import ReferenceNode as ReferenceNodeConfig
from tank_control.core.params import ConfigError, specs_of
from tank_control.core.reference import (FIELDS, Reference, channel_lists, channel_specs,
                                         split_param_name)
from tank_control.core.scenario import reference_setup
from tank_control.core.stamps import future_tolerance_ns, origin_refusal
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.messages import (CLOCK_QOS, ORIGIN_QOS, REFERENCE_QOS, TOPIC_CLOCK,
                                         TOPIC_DIAGNOSTICS, TOPIC_DISTURBANCE, TOPIC_SETPOINT,
                                         TOPIC_TIME_ORIGIN,
                                         quiet_publisher_events, quiet_subscription_events,
                                         stamp_to_ns)
from tank_control.nodes.cdr import cdr_stamp_ns
from tank_control.nodes.params import GroupedParameterService, ParameterBinding, ParameterError
from tank_control.nodes.protocol.reference import reference_clock
from tank_control.nodes.runtime import main as run_node_main


def _channel_values(node: Node) -> dict[str, Any]:
    """The node's start-up channel values from the params file / command line (flat)."""
    overrides = getattr(node, '_parameter_overrides', {})   # rclpy has no public getter
    return {name: (list(p.value) if not isinstance(p.value, (str, bytes))
                   and hasattr(p.value, '__len__') else p.value)
            for name, p in overrides.items() if name.split('.')[0] in ('setpoint', 'disturbance')}


def _channels(names: Iterable[str]) -> set[tuple[str, str]]:
    """(kind, channel) of the channel fields among ``names`` (``setpoint.y.times`` →
    ``('setpoint', 'y')``)."""
    return {(split[0], split[1]) for split in map(split_param_name, names) if split}

class ReferenceNode(Node):
    """Setpoint/disturbance publisher around a core ``Reference``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('reference', allow_undeclared_parameters=True,
                         start_parameter_services=False, **kwargs)
        self._parameter_service = GroupedParameterService(self)   # times + values together
        try:
            reference = reference_setup(_channel_values(self)).reference
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.reference: Reference = reference
        self.params = ParameterBinding(self, specs_of(ReferenceNodeConfig) + channel_specs(reference),
                                       cross_check=self._cross_check, derive=self._derive)
        self._pubs = {topic: self.create_publisher(JointState, topic, REFERENCE_QOS,
                                                   event_callbacks=quiet_publisher_events())
                      for topic in (TOPIC_SETPOINT, TOPIC_DISTURBANCE)}
        self.setpoint_pub, self.disturbance_pub = self._pubs.values()
        # the clock protocol (nodes/protocol/reference.py), picked once
        self.use_sim_time = bool(self.get_parameter('use_sim_time').value)
        mode = str(self.params.values['clock_mode'])
        self._protocol = reference_clock(mode, self.use_sim_time)(
            self, int(self.params.values['lockstep.lookahead']))
        if self._protocol.follows_clock:
            # taken as CDR bytes: only the stamp is read (nodes/cdr.py)
            self.create_subscription(
                Clock, TOPIC_CLOCK, self._on_clock,
                CLOCK_QOS, event_callbacks=quiet_subscription_events(), raw=True)
            # a plant on the wall clock latches a non-zero origin and sends no /clock
            self.create_subscription(Time, TOPIC_TIME_ORIGIN, self._check_origin, ORIGIN_QOS)
            self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
            self._conflict = ''
        else:
            period = float(self.params.values['sample_time'])
            self._timer = self.create_timer(period, self._on_timer, clock=steady_clock(),
                                            autostart=False)
            self.create_subscription(Time, TOPIC_TIME_ORIGIN, self._on_origin, ORIGIN_QOS)
            self.add_post_set_parameters_callback(self._after_set)
        sp, dist = channel_lists(self.params.values)
        self.get_logger().info(
            f'reference: setpoints {sp or "none"}, disturbances {dist or "none"}, ' + {
                'lockstep': f'lockstep, publishing {self.params.values["lockstep.lookahead"]} '
                            'ticks ahead, one message per change',
                'sim': 'answering /clock ticks',
                'wall': f'every {self.params.values["sample_time"]:g} s of plant time (waiting '
                        f"for the plant's {TOPIC_TIME_ORIGIN})"}[self._protocol.mode])

    # ------------------------------------------------------------- parameters
    def _trial(self, values: Mapping[str, Any], names: frozenset[str]) -> tuple[Reference, str | None]:
        """The running reference with the channel fields ``names`` set to ``values``, as from
        the latest published instant on: ``(reference, None)`` or ``(_, reason)``.

        ``value`` alone is an override (target from that instant on); ``min``/``max``/
        ``ramp_rate`` alone keep the future of the schedule and fold its past into the value
        reached (no past value is judged against new limits); ``times``/``values`` replace the
        schedule, and a ``value`` set with them is an override only when it is neither the new
        schedule's value at 0 nor its last target (what a dump holds)."""
        trial = copy.deepcopy(self.reference)
        by_channel: dict[tuple[str, str], dict[str, Any]] = {}
        for name in names:
            parts = split_param_name(name)
            if parts:
                by_channel.setdefault(parts[:2], {})[parts[2]] = values[name]
        for (kind, ch), changes in by_channel.items():
            value = changes.pop('value', None)
            reason = trial.update(kind, ch, changes, self._protocol.last_t) if changes else None
            if reason:
                return trial, reason
            if value is None:
                continue
            schedule = trial.schedule(kind, ch)
            if {'times', 'values'} & set(changes) and value in (schedule.at(0.0),
                                                                 schedule.values[-1]):
                continue
            reason = trial.update(kind, ch, {'value': value}, self._protocol.last_t)
            if reason:
                return trial, reason
        return trial, None

    def _cross_check(self, values: Mapping[str, Any], changed: frozenset[str]) -> str | None:
        """The change must leave every schedule valid: it is tried on a copy of the
        running reference, so nothing accepted here can be refused when it is applied."""
        if getattr(self, 'params', None) is None:
            return None          # start-up: reference_from_params has checked the file
        return self._trial(values, changed)[1]

    def _derive(self, values: Mapping[str, Any], changed: frozenset[str]) -> dict[str, Any]:
        """The schedule a change makes, as parameters set with it: ``times``/``values`` (and
        ``value``, the schedule's value at 0, unless the change is an override) of each channel
        it touches, so the parameters always equal what runs."""
        if getattr(self, 'params', None) is None:
            return {}            # start-up: the declared values are the file's schedules
        trial, reason = self._trial(values, changed)
        if reason:
            return {}            # refused by the cross-check, with this reason
        extra: dict[str, Any] = {}
        for kind, ch in _channels(changed):
            schedule, prefix = trial.schedule(kind, ch), f'{kind}.{ch}.'
            extra[prefix + 'times'] = list(schedule.times)
            extra[prefix + 'values'] = list(schedule.values)
            if prefix + 'value' not in changed:
                extra[prefix + 'value'] = schedule.at(0.0)
        return {k: v for k, v in extra.items() if k not in changed}

    def apply_pending(self, t: float) -> None:
        """Accepted parameter changes act from instant ``t`` [s] on: each channel touched runs
        exactly the schedule its parameters now hold."""
        pending = self.params.take_pending()   # (wall: a new sample_time acts at re-arming)
        values = self.params.values
        for kind, ch in sorted(_channels(pending)):
            prefix = f'{kind}.{ch}.'
            fields = {f: values[prefix + f] for f in FIELDS if f != 'value'}
            reason = self.reference.update(kind, ch, fields, t)
            if reason:   # never expected: the same schedule passed the cross-check
                self.get_logger().error(f'change of {kind}.{ch} not applied: {reason}')
            else:
                self.get_logger().info(f'{kind}.{ch}: times {fields["times"]}, values '
                                       f'{fields["values"]} from t = {t:g} s')

    def info(self, text: str) -> None:
        self.get_logger().info(text)

    # ---------------------------------------------------------------- publish
    def _on_clock(self, data: bytes) -> None:
        self._emit(self._protocol.clock(cdr_stamp_ns(data)))

    def _emit(self, messages: list[tuple[str, bytes]]) -> None:
        for topic, msg in messages:
            self._pubs[topic].publish(msg)

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
        """wall: the plant's time origin; (re)start the grid of instants from it (one far ahead
        of this node's clock is refused: ``core/stamps.origin_refusal``)."""
        ts_ns = to_ns(float(self.params.values['sample_time']))
        reason = origin_refusal(stamp_to_ns(msg), self._protocol.origin_ns,
                                self.get_clock().now().nanoseconds,
                                future_tolerance_ns(None, ts_ns / 1e9), ts_ns)
        if reason:
            self._refused_origins = getattr(self, '_refused_origins', 0) + 1
            if self._refused_origins in (1, 10, 100) or self._refused_origins % 1000 == 0:
                self.get_logger().warning(f'{reason} ({self._refused_origins} so far)')
            return
        if self._protocol.origin(stamp_to_ns(msg)):
            self._on_timer()

    def _after_set(self, parameters: list[Parameter]) -> None:
        """wall: a new ``sample_time`` re-arms the timer on the new grid at once (otherwise
        the wait for the next instant of the old grid, up to a whole old period, runs out
        first). rclpy calls post-set callbacks last-added first, so this runs before
        ParameterBinding stores the value: the period is taken from the request."""
        for param in parameters:
            if param.name == 'sample_time' and self._protocol.origin_ns is not None:
                self._on_timer(to_ns(float(param.value)))

    def _on_timer(self, period_ns: int | None = None) -> None:
        """wall: publish the latest instant reached (if not yet), re-arm for the next; an
        instant counts as reached ``wall.lead`` before it (the consumers hold values stamped
        ahead until their instant: ``nodes/clock.Scheduled``)."""
        self._timer.cancel()
        if period_ns is None:
            period_ns = to_ns(float(self.params.values['sample_time']))
        messages, wait_ns = self._protocol.timer(
            self.get_clock().now().nanoseconds, period_ns,
            to_ns(float(self.params.values['wall.lead'])))
        self._emit(messages)
        self._timer.timer_period_ns = wait_ns
        self._timer.reset()

def main(args: list[str] | None = None) -> int:
    """Console entry point reference_node; exit 2 with a one-line reason on bad parameters."""
    return run_node_main('reference_node', ReferenceNode, args)


if __name__ == '__main__':
    sys.exit(main())
