"""Signal messages, topic names and QoS shared by every node.

A signal is a ``sensor_msgs/msg/JointState``: ``header.stamp`` = the sample instant (integer
ns; ``origin + k·ts`` of the plant's time base), ``name[]`` = channels, ``position[]`` = values
in the channel's units. Time base, late answers and QoS: docs/nodes.md.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from builtin_interfaces.msg import Time
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.core.interfaces import NS_PER_S
from tank_control.nodes.cdr import signal_from_cdr
from tank_control.core.ranges import Ranges
from tank_control.core.stamps import MAX_NAMES

def reliable_qos(depth: int, latched: bool = False) -> QoSProfile:
    """Reliable keep-last ``depth``; ``latched``: transient local (a late joiner gets the
    last ``depth`` messages), else volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                  else DurabilityPolicy.VOLATILE))


#: Signal topics: reliable, keep-last 10, volatile.
SIGNAL_QOS = reliable_qos(10)
#: The reference's ``setpoint`` and ``disturbance`` writers: the signal QoS with a deeper
#: history. In lockstep they run ``lockstep.lookahead`` (<= 8) ticks ahead of the plant, which
#: runs up to ``lockstep.record_window`` (<= 8) ticks ahead of what the recorder holds: at most
#: 8 + 1 + 8 of their messages may not yet be taken by the recorder, and a reliable keep-last
#: writer drops the oldest beyond its depth (the depth is no part of QoS matching).
REFERENCE_QOS = reliable_qos(32)
#: ``/clock`` published by the plant (reliable keep-last 10; a best-effort
#: subscriber such as rclpy's own TimeSource still matches it).
CLOCK_QOS = reliable_qos(10)
#: ``~/late_inputs``: reliable and deep, so that a burst of reports on a loaded machine reaches a
#: slow reader (the harness's recorder) whole.
LATE_QOS = reliable_qos(1000)
#: ``time_origin`` (``builtin_interfaces/msg/Time``): the plant's time origin, latched —
#: reliable, transient local, keep-last 1, so a node that starts later still gets it.
ORIGIN_QOS = reliable_qos(1, latched=True)
#: ``applied_input``: the manipulated values the plant applies, latched (reliable, transient
#: local, keep-last 1) so that a controller that (re)starts on a running loop reads them.
APPLIED_QOS = reliable_qos(1, latched=True)

#: ``recorded``: reliable, transient local, keep-last 1 (the latest acknowledgment is all that
#: counts, and a plant that matches late still gets it).
RECORDED_QOS = reliable_qos(1, latched=True)


def quiet_publisher_events() -> PublisherEventCallbacks:
    """No default QoS-event handlers for a hot-path publisher.

    rclpy attaches an "incompatible QoS/type" handler to every endpoint by
    default; each is one more waitable the executor rebuilds its wait set with
    on every spin — measurable in lockstep, where a tick is a few callbacks.
    Our signal QoS (reliable) is compatible with reliable and best-effort
    readers alike, so the handlers have nothing to report.
    """
    return PublisherEventCallbacks(use_default_callbacks=False)


def quiet_subscription_events() -> SubscriptionEventCallbacks:
    """No default QoS-event handlers for a hot-path subscription (see above)."""
    return SubscriptionEventCallbacks(use_default_callbacks=False)


TOPIC_MEASUREMENT = 'measurement'
TOPIC_MANIPULATED = 'manipulated'
TOPIC_SETPOINT = 'setpoint'
TOPIC_DISTURBANCE = 'disturbance'
TOPIC_CLOCK = '/clock'
TOPIC_DIAGNOSTICS = '/diagnostics'
#: The ROS time of the plant's tick 0 (0 in sim/lockstep): plant time = stamp − origin.
TOPIC_TIME_ORIGIN = 'time_origin'
#: The plant's applied manipulated values (only the channels a controller has sent).
TOPIC_APPLIED_INPUT = 'applied_input'
#: The harness recorder's acknowledgment (``builtin_interfaces/Time``): the stamp of the last
#: tick it holds whole; a lockstep plant with ``lockstep.record_window`` runs at most that many
#: ticks ahead of it.
TOPIC_RECORDED = 'recorded'
#: Per node (``~/late_inputs``): answers that came after the node had used their tick.
TOPIC_LATE_INPUTS = '~/late_inputs'


#: sim/wall: longest wait before tick 0 for the middleware to match the endpoints the graph
#: shows on the plant's topics (plant_node ``_match_wait`` on its own view, the harness on
#: its view) [s of wall time]
MATCH_WAIT_S = 5.0


def unmatched(node: Any, publishers: Iterable[Any] = (),
              subscriptions: Iterable[Any] = ()) -> list[str]:
    """Topics of ``node`` with a reader (of a publisher) or a writer (of a subscription) the
    graph shows but the middleware has not matched yet. The graph comes from the
    participants' announcements (``ros_discovery_info``), the matching from the endpoint
    discovery, which a loaded machine can delay by seconds (a lost announcement waits for the
    next period): a message published in between never reaches that reader, a latched one
    only later."""
    return ([pub.topic_name for pub in publishers
             if pub.get_subscription_count() < node.count_subscribers(pub.topic_name)] +
            [sub.topic_name for sub in subscriptions
             if sub.get_publisher_count() < node.count_publishers(sub.topic_name)])


def ns_to_stamp(t_ns: int) -> Time:
    """Integer nanoseconds → ``builtin_interfaces/Time`` (exact)."""
    sec, nanosec = divmod(int(t_ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def stamp_to_ns(stamp: Time) -> int:
    """``builtin_interfaces/Time`` → integer nanoseconds (exact)."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def to_joint_state(t_ns: int, names: Sequence[str], values: Iterable[float]) -> JointState:
    """A signal message: stamp ``t_ns``, channels ``names`` with ``values``."""
    msg = JointState()
    msg.header.stamp = ns_to_stamp(t_ns)
    msg.name = list(names)
    msg.position = [float(v) for v in values]
    return msg


def parse_signal(msg: JointState | bytes, max_names: int | None = MAX_NAMES
                 ) -> tuple[int, str, tuple[str, ...], tuple[float, ...]]:
    """``(stamp_ns, frame_id, names, values)`` of a signal message: a ``JointState`` or its CDR
    bytes (what a ``raw=True`` subscription takes; decoded directly, ``nodes/cdr.py``).

    Raises ``ValueError`` (one line) when ``name`` and ``position`` differ in
    length, a channel name repeats, or there are more than ``max_names`` names
    (``core/stamps.MAX_NAMES``; refused before they are decoded: bounded work per
    message) — a malformed message.
    """
    if isinstance(msg, bytes):
        stamp, frame_id, names, values = signal_from_cdr(msg, max_names)
    else:
        if max_names is not None and len(msg.name) > max_names:
            raise ValueError(f'{len(msg.name)} channel names, at most {max_names} taken')
        names = tuple(msg.name)
        values = tuple(float(v) for v in msg.position)
        stamp, frame_id = stamp_to_ns(msg.header.stamp), msg.header.frame_id
    if len(names) != len(values):
        raise ValueError(f'{len(names)} names but {len(values)} positions')
    if len(set(names)) != len(names):
        raise ValueError(f'repeated channel name in {list(names)}')
    return stamp, frame_id, names, values


def from_joint_state(msg: JointState | bytes) -> tuple[int, tuple[str, ...], tuple[float, ...]]:
    """``(stamp_ns, names, values)`` of a signal message (``parse_signal`` without the frame id).

    Raises ``ValueError`` (one line) when ``name`` and ``position`` differ in
    length or a channel name repeats — a malformed message.
    """
    stamp, _, names, values = parse_signal(msg)
    return stamp, names, values


def clock_msg(t_ns: int) -> Clock:
    """``rosgraph_msgs/Clock`` for the instant ``t_ns``."""
    return Clock(clock=ns_to_stamp(t_ns))


@dataclass
class ChannelFilter:
    """Accepts channel values by name; counts and explains what it ignores.

    A value is ignored (the last valid one is kept by the caller) when the
    message is malformed (also one with more than ``MAX_NAMES`` names:
    ``oversized``), the channel is not one of ``known`` (``unknown``) or the value
    is not finite or outside the channel's plausible range (``ranges``,
    ``core/ranges.py``; also counted in ``out_of_range``). Every ignored item is
    counted in ``ignored``. Each kind of reason (per topic; per channel for a known
    one) is reported once through ``accept``'s new reasons, until ``rearm``
    (a node calls it once per diagnostics period: a rate-limited log whose lines
    give the counts); the reasons held are bounded by the known channels, not by
    what a message carries.
    """

    known: tuple[str, ...]
    ignored: int = 0
    reasons: set[str] = field(default_factory=set)
    ranges: Ranges = field(default_factory=Ranges)
    out_of_range: int = 0
    unknown: int = 0
    oversized: int = 0

    def accept(self, topic: str, msg: JointState | bytes
               ) -> tuple[int | None, tuple[str, ...], dict[str, float], list[str]]:
        """``(stamp_ns or None, the message's channel names, accepted {name: value}, new
        reasons to log)``; ``msg`` a JointState or its CDR bytes."""
        new: list[str] = []
        try:
            t_ns, _, names, values = parse_signal(msg)
        except ValueError as err:
            self.ignored += 1
            if 'at most' in str(err):
                self.oversized += 1
            self._note(f'{topic}/malformed', f'{topic}: malformed message ignored ({err}); '
                       f'{self.ignored} ignored so far', new)
            return None, (), {}, new
        accepted: dict[str, float] = {}
        unknown: list[str] = []
        for name, value in zip(names, values):
            if name not in self.known:
                unknown.append(name)
            elif not math.isfinite(value):
                self.ignored += 1
                self._note(f'{topic}/{name}/nonfinite',
                           f'{topic}: non-finite value for {name!r} ignored; last valid kept', new)
            elif not self.ranges.accepts(name, value):
                self.ignored += 1
                self.out_of_range += 1
                self._note(f'{topic}/{name}/range',
                           f'{topic}: {self.ranges.reason(name, value)} ignored; last valid kept',
                           new)
            else:
                accepted[name] = value
        if unknown:
            self.ignored += len(unknown)
            self.unknown += len(unknown)
            shown = ', '.join(repr(n[:40]) for n in unknown[:3])
            more = f' and {len(unknown) - 3} more' if len(unknown) > 3 else ''
            self._note(f'{topic}/unknown',
                       f'{topic}: unknown channel(s) {shown}{more} ignored ({self.unknown} so '
                       f'far); known: {", ".join(self.known) or "none"}', new)
        return t_ns, names, accepted, new

    def rearm(self) -> None:
        """Report each kind of reason again (once per diagnostics period)."""
        self.reasons.clear()

    def _note(self, key: str, reason: str, new: list[str]) -> None:
        if key not in self.reasons:
            self.reasons.add(key)
            new.append(reason)
