"""reference_node: publishes the setpoint and disturbance schedules of ``core/reference.py``.

Publishes ``setpoint`` and ``disturbance`` (``sensor_msgs/JointState`` by channel name): in
``wall`` mode every ``sample_time`` of plant time from the plant's ``time_origin`` on, in ``sim``
one idempotent answer per ``/clock`` tick, in ``lockstep`` the schedules ``lockstep.lookahead``
ticks ahead under zero-order hold (a message per change, ``_HeldStream``). The channel
parameters always equal the schedules it runs: a change (an override ``value``, new limits) is
written back to ``times``/``values``, and several parameters set in one call (``ros2 param
load``) are one atomic change. Parameter layout, runtime overrides and timing: docs/nodes.md
("reference_node"). Times in s.
"""
from __future__ import annotations

import copy
import sys
from collections.abc import Callable
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
from tank_control.core.reference import (FIELDS, Reference, channel_lists, channel_specs,
                                         split_param_name)
from tank_control.core.scenario import reference_setup
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.messages import (CLOCK_QOS, ORIGIN_QOS, REFERENCE_QOS, TOPIC_CLOCK,
                                         TOPIC_DIAGNOSTICS, TOPIC_DISTURBANCE, TOPIC_SETPOINT,
                                         TOPIC_TIME_ORIGIN,
                                         quiet_publisher_events, quiet_subscription_events,
                                         stamp_to_ns)
from tank_control.nodes.cdr import JointStateCdr, cdr_stamp_ns
from tank_control.nodes.params import GroupedParameterService, ParameterBinding, ParameterError
from tank_control.nodes.runtime import main as run_node_main


def _channel_values(node: Node) -> dict[str, Any]:
    """The node's start-up channel values from the params file / command line (flat)."""
    overrides = getattr(node, '_parameter_overrides', {})   # rclpy has no public getter
    return {name: (list(p.value) if not isinstance(p.value, (str, bytes))
                   and hasattr(p.value, '__len__') else p.value)
            for name, p in overrides.items() if name.split('.')[0] in ('setpoint', 'disturbance')}


class _HeldStream:
    """lockstep: one topic's messages under zero-order hold (``lockstep.lookahead``): a message
    per change of its values, and one at the horizon whenever the consumers would otherwise
    not know the next tick (``nodes/clock.Held`` is the consumers' side)."""

    def __init__(self, publisher: Any) -> None:
        self.pub = publisher
        self.last: tuple | None = None      # (names, values) of the latest message
        self.sent: list[tuple[int, bytes]] = []   # from the one in force at the tick on

    def offer(self, stamp_ns: int, names: tuple[str, ...], values: tuple[float, ...],
              encoder: Callable[[tuple[str, ...]], JointStateCdr]) -> None:
        """The values at ``stamp_ns``: published when they differ from the last message's."""
        if (names, values) != self.last:
            self._send(stamp_ns, names, values, encoder(names))

    def hold(self, stamp_ns: int, need_ns: int,
             encoder: Callable[[tuple[str, ...]], JointStateCdr]) -> None:
        """Publish the values held at ``stamp_ns`` if no message is stamped at or after
        ``need_ns`` (the next tick the consumers must know)."""
        if self.last is not None and self.sent[-1][0] < need_ns:
            self._send(stamp_ns, *self.last, encoder(self.last[0]))

    def _send(self, stamp_ns: int, names: tuple[str, ...], values: tuple[float, ...],
              encoder: JointStateCdr) -> None:
        msg = encoder.encode_ns(stamp_ns, values)
        self.last = (names, values)
        self.sent.append((stamp_ns, msg))
        self.pub.publish(msg)

    def prune(self, t_ns: int) -> None:
        """Keep the message in force at ``t_ns`` and the later ones (what a re-send sends)."""
        keep = 0
        while keep + 1 < len(self.sent) and self.sent[keep + 1][0] <= t_ns:
            keep += 1
        del self.sent[:keep]

    def resend(self) -> None:
        for _, msg in self.sent:
            self.pub.publish(msg)


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
        self._last_t = 0.0                 # the latest instant published (lockstep: evaluated) [s]
        self.params = ParameterBinding(self, specs_of(ReferenceNodeConfig) + channel_specs(reference),
                                       cross_check=self._cross_check, derive=self._derive)
        self.setpoint_pub = self.create_publisher(JointState, TOPIC_SETPOINT, REFERENCE_QOS,
                                                  event_callbacks=quiet_publisher_events())
        self.disturbance_pub = self.create_publisher(JointState, TOPIC_DISTURBANCE, REFERENCE_QOS,
                                                     event_callbacks=quiet_publisher_events())
        # answers as pre-encoded CDR (nodes/cdr.py), by channel names
        self._answered: dict[int, tuple[bytes, bytes]] = {}
        self._encoders: dict[tuple[str, ...], JointStateCdr] = {}
        self._last_clock: int | None = None
        # Zero-order hold only in an explicit lockstep: in sim the others use the latest
        # message, which must be the current tick's (use_sim_time alone does not tell sim
        # from lockstep).
        self._held = self.params.values['clock_mode'] == 'lockstep'
        self._lookahead = int(self.params.values['lockstep.lookahead'])
        self._streams = self._held_streams()
        self._period_ns: int | None = None  # lockstep: the plant's tick, from two /clock ticks
        self._horizon_ns = -1               # lockstep: the latest instant evaluated [ns]
        self.use_sim_time = (bool(self.get_parameter('use_sim_time').value)
                             or self.params.values['clock_mode'] != 'wall')
        if self.use_sim_time:
            # taken as CDR bytes: only the stamp is read (nodes/cdr.py)
            self.create_subscription(Clock, TOPIC_CLOCK,
                                     self._on_clock_held if self._held else self._on_clock,
                                     CLOCK_QOS, event_callbacks=quiet_subscription_events(),
                                     raw=True)
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
            + (f'lockstep, publishing {self._lookahead} ticks ahead, one message per change'
               if self._held else 'answering /clock ticks' if self.use_sim_time else
               f'every {period:g} s of plant time (waiting for the plant\'s {TOPIC_TIME_ORIGIN})'))

    # ------------------------------------------------------------- parameters
    def _trial(self, values: dict[str, Any], names: frozenset[str]) -> tuple[Reference, str | None]:
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
            reason = trial.update(kind, ch, changes, self._last_t) if changes else None
            if reason:
                return trial, reason
            if value is None:
                continue
            schedule = trial.schedule(kind, ch)
            if {'times', 'values'} & set(changes) and value in (schedule.at(0.0),
                                                                 schedule.values[-1]):
                continue
            reason = trial.update(kind, ch, {'value': value}, self._last_t)
            if reason:
                return trial, reason
        return trial, None

    def _cross_check(self, values: dict[str, Any], changed: frozenset[str]) -> str | None:
        """The change must leave every schedule valid: it is tried on a copy of the
        running reference, so nothing accepted here can be refused when it is applied."""
        if getattr(self, 'params', None) is None:
            return None          # start-up: reference_from_params has checked the file
        return self._trial(values, changed)[1]

    def _derive(self, values: dict[str, Any], changed: frozenset[str]) -> dict[str, Any]:
        """The schedule a change makes, as parameters set with it: ``times``/``values`` (and
        ``value``, the schedule's value at 0, unless the change is an override) of each channel
        it touches, so the parameters always equal what runs."""
        if getattr(self, 'params', None) is None:
            return {}            # start-up: the declared values are the file's schedules
        trial, reason = self._trial(values, changed)
        if reason:
            return {}            # refused by the cross-check, with this reason
        extra: dict[str, Any] = {}
        for kind, ch in {split_param_name(n)[:2] for n in changed if split_param_name(n)}:
            schedule, prefix = trial.schedule(kind, ch), f'{kind}.{ch}.'
            extra[prefix + 'times'] = list(schedule.times)
            extra[prefix + 'values'] = list(schedule.values)
            if prefix + 'value' not in changed:
                extra[prefix + 'value'] = schedule.at(0.0)
        return {k: v for k, v in extra.items() if k not in changed}

    def _apply_pending(self, t: float) -> None:
        """Accepted parameter changes act from instant ``t`` [s] on: each channel touched runs
        exactly the schedule its parameters now hold."""
        pending = self.params.take_pending()   # (wall: a new sample_time acts at re-arming)
        values = self.params.values
        for kind, ch in sorted({split_param_name(n)[:2] for n in pending if split_param_name(n)}):
            prefix = f'{kind}.{ch}.'
            fields = {f: values[prefix + f] for f in FIELDS if f != 'value'}
            reason = self.reference.update(kind, ch, fields, t)
            if reason:   # never expected: the same schedule passed the cross-check
                self.get_logger().error(f'change of {kind}.{ch} not applied: {reason}')
            else:
                self.get_logger().info(f'{kind}.{ch}: times {fields["times"]}, values '
                                       f'{fields["values"]} from t = {t:g} s')

    # ---------------------------------------------------------------- publish
    def _publish(self, stamp_ns: int, t: float) -> None:
        self._last_t = max(self._last_t, t)
        self._apply_pending(t)
        ref = self.reference
        sp = self._encoder(ref.setpoint_names).encode_ns(stamp_ns, ref.setpoints(t))
        dist = self._encoder(ref.disturbance_names).encode_ns(stamp_ns, ref.disturbances(t))
        self._answered[stamp_ns] = (sp, dist)
        self.setpoint_pub.publish(sp)
        self.disturbance_pub.publish(dist)

    def _encoder(self, names: tuple[str, ...]) -> JointStateCdr:
        encoder = self._encoders.get(names)
        if encoder is None:
            encoder = self._encoders[names] = JointStateCdr(names)
        return encoder

    def _held_streams(self) -> tuple[_HeldStream, _HeldStream]:
        return _HeldStream(self.setpoint_pub), _HeldStream(self.disturbance_pub)

    def _on_clock_held(self, msg: bytes) -> None:
        """lockstep: on /clock t_k make the schedules known through t_k + ``lookahead`` ticks
        (zero-order hold: a message per change, ``_HeldStream``), so that the controller and
        the plant of the next ticks wait for nobody but each other; a re-sent /clock t_k gets
        again every message from the one in force at t_k on. ``msg``: the CDR bytes of a
        ``rosgraph_msgs/Clock``."""
        t_ns = cdr_stamp_ns(msg)
        if self._last_clock is not None and t_ns < self._last_clock:
            # /clock went back: the plant (re)started, a new run
            self.get_logger().info('/clock restarted: answering a new run')
            self._last_clock, self._period_ns, self._horizon_ns = None, None, -1
            self._last_t = 0.0
            self._streams = self._held_streams()
        if t_ns == self._last_clock:             # the plant re-sent tick k
            for stream in self._streams:
                stream.resend()
            return
        if self._last_clock is not None:     # the plant's ticks are evenly spaced
            step = t_ns - self._last_clock
            self._period_ns = step if self._period_ns is None else min(self._period_ns, step)
        self._last_clock = t_ns
        period = self._period_ns
        ahead = self._lookahead if period else 0
        target = t_ns + ahead * (period or 0)
        j = t_ns if self._horizon_ns < t_ns or not period else self._horizon_ns + period
        ref = self.reference
        setpoints, disturbances = self._streams
        while j <= target:
            t = seconds(j)
            self._last_t = max(self._last_t, t)
            self._apply_pending(t)
            setpoints.offer(j, ref.setpoint_names, tuple(ref.setpoints(t).tolist()),
                            self._encoder)
            disturbances.offer(j, ref.disturbance_names, tuple(ref.disturbances(t).tolist()),
                               self._encoder)
            if not period:
                break                            # tick 0: the tick period is not known yet
            j += period
        self._horizon_ns = max(self._horizon_ns, target)
        need = t_ns + period if ahead else t_ns  # the consumers' next tick (this one: without)
        for stream in self._streams:
            stream.hold(self._horizon_ns, need, self._encoder)
            stream.prune(t_ns)

    def _on_clock(self, msg: bytes) -> None:
        """sim: answer tick t_k once (idempotent: a re-sent /clock gets the same messages).
        ``msg``: the CDR bytes of a ``rosgraph_msgs/Clock``."""
        t_ns = cdr_stamp_ns(msg)
        if self._last_clock is not None and t_ns < self._last_clock:
            # /clock went back: the plant (re)started, a new run (the plant re-sends only its
            # current tick, so an earlier one is no duplicate; its tick 0 may have been missed)
            self.get_logger().info('/clock restarted: answering a new run')
            self._answered.clear()
            self._last_clock = None
            self._last_t = 0.0
        if self._last_clock is not None and t_ns < self._last_clock:
            return                        # a stale duplicate of an earlier tick
        cached = self._answered.get(t_ns)
        if t_ns == self._last_clock and cached is not None:   # the plant re-sent tick k
            for pub, answer in zip((self.setpoint_pub, self.disturbance_pub), cached):
                pub.publish(answer)
            return
        self._last_clock = t_ns
        for stamp in [s for s in self._answered if s < t_ns]:
            del self._answered[stamp]
        if cached is None:
            self._publish(t_ns, seconds(t_ns))

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
        self._origin_ns, self._last_t_ns, self._last_t = origin, -1, 0.0
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
        """wall: publish the latest instant reached (if not yet), re-arm for the next; an
        instant counts as reached ``wall.lead`` before it (the consumers hold values stamped
        ahead until their instant: ``nodes/clock.Scheduled``)."""
        self._timer.cancel()
        if period_ns is None:
            period_ns = to_ns(float(self.params.values['sample_time']))
        # ``wall.lead``: instant j is published at t_j - lead (stamped t_j), half a period at most
        lead_ns = min(to_ns(float(self.params.values['wall.lead'])), period_ns // 2)
        elapsed = self.get_clock().now().nanoseconds - self._origin_ns + lead_ns
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
