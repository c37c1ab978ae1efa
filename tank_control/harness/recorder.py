"""The recorder node that lives in the harness process: it subscribes to every topic of
the loop and hands each serialized message to a sink as it arrives (the harness writes it
to ``run.mcap`` and joins the signals into ``trace.csv`` at once; without a sink the
messages are kept in ``messages``, for short recordings in tests), and reads the
controller's final parameters through its parameter services."""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from typing import Any

from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future

from tank_control.core.stamps import MAX_NAMES, FutureStamps
from tank_control.harness.recording import RawMessage
from tank_control.nodes.clock import steady_clock
from tank_control.harness.trace import GATED_DISTURBANCE, TOPIC_PREFIX, SignalMessage
from tank_control.nodes.cdr import (JointStateCdr, cdr_stamp_ns,  # noqa: F401 (re-exported)
                                    joint_state_from_cdr, signal_from_cdr, time_cdr_ns)
from tank_control.nodes.clock import Held
from tank_control.nodes.messages import (ORIGIN_QOS, RECORDED_QOS, SIGNAL_QOS, TOPIC_RECORDED,
                                         quiet_publisher_events, quiet_subscription_events)
from tank_control.nodes.services import RESEND_AFTER, answer, prime

#: The recorder's node name (another graph's recorder on the domain is another run).
RECORDER_NAME = 'tank_control_recorder'

#: (topic, type) of everything recorded. Signal topics are relative names (remapping works).
TOPICS: tuple[tuple[str, str], ...] = (
    ('measurement', 'sensor_msgs/msg/JointState'),
    ('setpoint', 'sensor_msgs/msg/JointState'),
    ('manipulated', 'sensor_msgs/msg/JointState'),
    ('disturbance', 'sensor_msgs/msg/JointState'),
    ('/clock', 'rosgraph_msgs/msg/Clock'),
    ('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray'),
    ('/parameter_events', 'rcl_interfaces/msg/ParameterEvent'),
    ('/parameter_audit', 'std_msgs/msg/String'),       # nodes/params.py AUDIT_TOPIC
    ('time_origin', 'builtin_interfaces/msg/Time'),
    ('plant/late_inputs', 'sensor_msgs/msg/JointState'),
    ('controller/late_inputs', 'sensor_msgs/msg/JointState'),
    # controller_node's live loop assessments (nodes/loop_performance.py, docs/monitoring.md)
    ('controller/loop_performance', 'std_msgs/msg/String'),
    ('controller/loop_mode', 'std_msgs/msg/String'),
)

#: Types recorded at their arrival time: no header stamp in the loop's time.
UNSTAMPED = ('diagnostic_msgs/msg/DiagnosticArray', 'rcl_interfaces/msg/ParameterEvent',
             'std_msgs/msg/String')

# Reliable like the publishers, keep-all: the reader's queue never drops a message the
# harness has not taken yet (with ``acknowledge``, the plant's window bounds it).
RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
#: Longest wait before a tick the recorder holds is acknowledged even if fewer than
#: ``every`` ticks came since the last acknowledgment (a plant waiting to re-send) [s].
ACK_PERIOD = 0.05
#: ``time_origin`` is latched by the plant (transient local): a late joiner still gets it.
ORIGIN_RECORD_QOS = ORIGIN_QOS
GATE_QOS = SIGNAL_QOS
_GATE_NEEDS = ('measurement', 'setpoint', 'manipulated', 'disturbance')
#: The recorder refuses a signal message stamped more than this many plant ticks (and at least
#: ``FUTURE_MIN_S``) ahead of its now — the latest ``/clock``, or its wall clock without one:
#: wider than the nodes' ``max_future_stamp`` (the reference's lookahead, a recorder that lags
#: the plant's ``/clock``), enough that one stray message cannot end a run, advance the
#: acknowledgments or enter the trace (docs/nodes.md, "Stamps from the future").
FUTURE_TICKS = 64
FUTURE_MIN_S = 1.0


def _message_class(type_name: str) -> type:
    package, _, name = type_name.split('/')
    module = __import__(f'{package}.msg', fromlist=[name])
    return getattr(module, name)


def signal_message(raw: RawMessage) -> SignalMessage:
    """A recorded JointState message as the trace join reads it; ``ValueError`` for one with
    more than ``MAX_NAMES`` names (refused before they are decoded: one message of 100 000
    names would be 100 000 trace columns) or malformed."""
    stamp, _, names, values = signal_from_cdr(raw.data, MAX_NAMES)
    return SignalMessage(raw.topic.lstrip('/'), stamp, names, values)


Sink = Callable[[RawMessage], None]


class Recorder:
    """Subscriptions on a node of its own (in ``context``), spun by ``spin_once``.

    ``subscribe=False`` creates the node only (its participant joins the domain before the
    harness has made the output directory) and ``subscribe(sink)`` starts recording. Each message goes to
    ``sink`` as it arrives; without a sink it is kept in ``messages``."""

    def __init__(self, context: Context, name: str = RECORDER_NAME, sink: Sink | None = None,
                 subscribe: bool = True, tick_ns: int | None = None) -> None:
        self.node = Node(name, context=context)
        # signal messages stamped too far ahead are refused (not recorded), counted; the tick
        # is the plant's sample time if given, else learned from /clock (sim, lockstep)
        self._future_min_ns = max(FUTURE_TICKS * (tick_ns or 0), int(FUTURE_MIN_S * 1e9))
        self.future = FutureStamps(self._future_min_ns)
        self.clock_ns: int | None = None     # the latest /clock (sim, lockstep) [ns]
        self._clock_tick: int | None = None  # the smallest step of /clock seen [ns]
        # rclpy's C++ events executor: a third of the CPU per message of the
        # SingleThreadedExecutor (bench/RESULTS.md, "Lockstep"); spun by spin_once only
        # (tank_control/nodes/runtime.py says why).
        self.executor = EventsExecutor(context=context)
        self.executor.add_node(self.node)
        self._never = Future()              # spin_for: never done, only the timeout ends it
        self.messages: list[RawMessage] = []
        self.sink: Sink = sink if sink is not None else self.messages.append
        self.latest: dict[str, int] = {}        # topic → largest stamp seen [ns]
        self.first: dict[str, int] = {}         # topic → first stamp seen [ns]
        self.counts: dict[str, int] = {}
        self._gate_pub: Any = None
        self._gate_stamps: dict[str, set[int]] = {}    # measurement, manipulated
        self._gate_held: dict[str, Held] = {}          # setpoint, disturbance (zero-order hold)
        self._gate_names: tuple[str, ...] = ()         # the disturbance channels
        self._gate_last: tuple[int, bytes] | None = None   # the last tick relayed
        self.relayed = 0
        self._ack_pub: Any = None
        self._ack_needs: frozenset[str] = frozenset()   # empty: no acknowledgments
        self._ack_every_ns = 0
        self.acked_ns = -1                  # stamp of the last acknowledged tick [ns]
        self.acknowledged = 0
        self._subscribed = False
        self._subscriptions: dict[str, Any] = {}
        if subscribe:
            self.subscribe()

    def subscribe(self, sink: Sink | None = None) -> None:
        """Start recording every topic of ``TOPICS`` (into ``sink`` if given)."""
        if sink is not None:
            self.sink = sink
        if self._subscribed:
            return
        self._subscribed = True
        for topic, type_name in TOPICS:
            qos = ORIGIN_RECORD_QOS if topic == 'time_origin' else RECORD_QOS
            self._subscriptions[topic.lstrip('/')] = self.node.create_subscription(
                _message_class(type_name), topic, self._callback(topic, type_name), qos,
                raw=True, event_callbacks=quiet_subscription_events())

    def matched_publishers(self, topic: str) -> int:
        """Publishers of ``topic`` the recorder's own reader has matched (0 before
        ``subscribe``): a graph entry alone does not mean its messages reach the recorder."""
        sub = self._subscriptions.get(topic.lstrip('/'))
        return sub.get_publisher_count() if sub is not None else 0

    def _callback(self, topic: str, type_name: str) -> Callable[[bytes], None]:
        full = topic if topic.startswith('/') else '/' + topic
        key = topic.lstrip('/')
        stamped = type_name not in UNSTAMPED
        counts, first, latest = self.counts, self.first, self.latest
        gate_topic = key in _GATE_NEEDS
        is_clock = key == 'clock'
        time_ns, monotonic_ns = time.time_ns, time.monotonic_ns
        future = self.future

        # Per message (5 a lockstep tick): one copy of the bytes into the sink, the counters;
        # names and flags bound once here, not looked up per message.
        def record(data: bytes) -> None:
            now = time_ns()
            stamp = cdr_stamp_ns(data) if stamped else now
            if is_clock:
                last = self.clock_ns
                if last is not None and stamp > last and (self._clock_tick is None
                                                          or stamp - last < self._clock_tick):
                    self._clock_tick = stamp - last
                    future.tolerance_ns = max(self._future_min_ns,
                                              FUTURE_TICKS * self._clock_tick)
                self.clock_ns = stamp
            elif gate_topic and not future.admit(
                    key, stamp, now if self.clock_ns is None else self.clock_ns, monotonic_ns()):
                for line in future.take_report():
                    self.node.get_logger().warning(line + ' (not recorded)')
                return
            self.sink(RawMessage(full, type_name, bytes(data), now, stamp))
            counts[key] = counts.get(key, 0) + 1
            if stamped:
                if key not in first:
                    first[key] = stamp
                if stamp > latest.get(key, -1):
                    latest[key] = stamp
                if gate_topic and self._gate_pub is not None:
                    self._gate(key, stamp, data)
                if key in self._ack_needs:
                    self._acknowledge(self._ack_every_ns)
        return record

    def acknowledge(self, needs: Iterable[str], every_ns: int) -> None:
        """Lockstep flow control off the tick's serial path (the plant's
        ``lockstep.record_window``): publish on ``recorded`` the stamp of the last tick whose
        ``needs`` topics (the signals the graph's nodes publish) the recorder holds, each
        time that advanced by ``every_ns`` and at least every :data:`ACK_PERIOD` while it
        advanced. Held = the smallest latest stamp over ``needs``: each topic's messages come
        in order, and none is lost (``PlantNode._on_recorded`` says why)."""
        from builtin_interfaces.msg import Time
        self._ack_needs = frozenset(needs)
        self._ack_every_ns = every_ns
        self._ack_pub = self.node.create_publisher(Time, TOPIC_RECORDED, RECORDED_QOS)
        self.node.create_timer(ACK_PERIOD, lambda: self._acknowledge(0),
                               clock=steady_clock())

    def _acknowledge(self, every_ns: int) -> None:
        latest = self.latest
        held = min(latest.get(t, -1) for t in self._ack_needs)
        if held >= 0 and held > self.acked_ns and (self.acked_ns < 0
                                                   or held - self.acked_ns >= every_ns):
            self.acked_ns = held
            self._ack_pub.publish(time_cdr_ns(held))     # pre-encoded: no rclpy message
            self.acknowledged += 1

    def enable_gate(self) -> None:
        """Lockstep back-pressure (node tests): the plant's ``disturbance`` input is remapped
        to ``disturbance_gated``, and the recorder publishes there, for each tick in order, the
        disturbance values in force at it, stamped with it, only once it has recorded that
        tick's measurement and manipulated and the reference's setpoint and disturbance
        streams through it (zero-order hold: ``nodes/clock.Held``). The plant cannot start
        tick k+1 before the recording holds all of tick k, so a busy machine slows the run
        instead of losing samples (signal publishers keep only their last messages for a
        slow reader)."""
        from sensor_msgs.msg import JointState
        self._gate_stamps = {'measurement': set(), 'manipulated': set()}
        self._gate_held = {'setpoint': Held(), 'disturbance': Held()}
        self._gate_pub = self.node.create_publisher(JointState, GATED_DISTURBANCE, GATE_QOS,
                                                    event_callbacks=quiet_publisher_events())

    def _gate(self, topic: str, stamp: int, data: bytes) -> None:
        held = self._gate_held.get(topic)
        if held is not None:
            _, names, values = joint_state_from_cdr(data)
            held.put(stamp, dict(zip(names, values)))
            if topic == 'disturbance' and names:
                self._gate_names = tuple(names)
        elif self._gate_last is not None and topic == 'measurement' and stamp == self._gate_last[0]:
            self._gate_pub.publish(self._gate_last[1])   # the plant re-sent the tick relayed
            return
        else:
            self._gate_stamps[topic].add(stamp)
        measured, manipulated = self._gate_stamps['measurement'], self._gate_stamps['manipulated']
        setpoint, disturbance = self._gate_held['setpoint'], self._gate_held['disturbance']
        for tick in sorted(measured):
            if (tick not in manipulated or setpoint.through < tick
                    or disturbance.through < tick):
                break
            values = disturbance.values(tick)
            names = self._gate_names
            msg = JointStateCdr(names).encode_ns(tick, [values.get(n, math.nan) for n in names])
            self._gate_pub.publish(msg)
            self._gate_last = (tick, msg)
            self.relayed += 1
            for seen in (measured, manipulated):      # ticks up to this one are done
                seen.difference_update([s for s in seen if s <= tick])
            setpoint.fold_until(tick)
            disturbance.fold_until(tick)

    def subscriber_count(self, topic: str) -> int:
        return self.node.count_subscribers(topic)

    def subscriber_nodes(self, topic: str) -> set[str]:
        """Names of the nodes subscribed to ``topic`` (relative names resolve to ``/topic``)."""
        full = topic if topic.startswith('/') else '/' + topic
        return {info.node_name for info in self.node.get_subscriptions_info_by_topic(full)}

    def spin_once(self, timeout: float) -> None:
        """Handle at most one message (or timer), waiting up to ``timeout`` wall seconds."""
        self.executor.spin_once(timeout_sec=timeout)

    def spin_for(self, duration: float) -> None:
        """Handle every message that comes within ``duration`` wall seconds, in one call into
        the executor. The EventsExecutor's ``spin_once`` returns after each message, so a
        loop around it pays a Python round trip (the loop's checks, the call) per message,
        five a lockstep tick; here the executor runs the callbacks back to back until the
        time is up (``spin_until_future_complete`` on a future that is never done: it
        returns at the timeout; no callback accumulates on the future, 2000 calls checked).
        A signal's Python handler runs inside the next callback, or at the latest when
        this returns."""
        self.executor.spin_until_future_complete(self._never, timeout_sec=duration)

    def drain(self, timeout: float, quiet: float = 0.1) -> None:
        """Take in what was already sent (after the publishers stopped): spin until no message
        came for ``quiet`` seconds, at most ``timeout`` wall seconds."""
        deadline = time.monotonic() + timeout
        last, last_change = sum(self.counts.values()), time.monotonic()
        while (now := time.monotonic()) < deadline and now - last_change < quiet:
            self.spin_once(0.02)
            count = sum(self.counts.values())
            if count != last:
                last, last_change = count, time.monotonic()

    def spin_until(self, condition: Callable[[], bool], timeout: float,
                   check: Callable[[], None] = lambda: None) -> bool:
        """Spin until ``condition()`` holds (True) or ``timeout`` wall seconds pass (False);
        ``check()`` runs every iteration and may raise (a node died)."""
        deadline = time.monotonic() + timeout
        while not condition():
            check()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self.spin_once(min(0.05, remaining))
        return True

    def node_names(self) -> set[str]:
        return set(self.node.get_node_names())

    def node_counts(self) -> dict[str, int]:
        """How many nodes of each name the graph holds (two ``plant``s: two graphs on one domain)."""
        counts: dict[str, int] = {}
        for name, namespace in self.node.get_node_names_and_namespaces():
            key = name if namespace == '/' else f'{namespace.rstrip("/")}/{name}'
            counts[key] = counts.get(key, 0) + 1
        return counts

    def signal_messages(self, topics: Iterable[str] = TOPIC_PREFIX) -> list[SignalMessage]:
        """The kept messages (no sink) of JointState ``topics`` (default: the signals)."""
        wanted = set(topics)
        out = []
        for raw in self.messages:
            if raw.topic.lstrip('/') in wanted:
                try:
                    out.append(signal_message(raw))
                except ValueError:
                    pass                 # too many names or malformed: in run.mcap only
        return out

    def node_parameters(self, node: str, timeout: float = 5.0,
                        check: Callable[[], None] = lambda: None) -> dict[str, Any]:
        """Every parameter of ``/node`` (through its list/get services); {} if it does not answer."""
        lister = self.node.create_client(ListParameters, f'/{node}/list_parameters')
        getter = self.node.create_client(GetParameters, f'/{node}/get_parameters')
        try:
            if not self.spin_until(lambda: lister.service_is_ready() and getter.service_is_ready(),
                                   timeout, check):
                return {}
            listed = self._call(lister, ListParameters.Request(), timeout, check, RESEND_AFTER)
            if listed is None:
                return {}
            names = list(listed.result.names)
            got = self._call(getter, GetParameters.Request(names=names), timeout, check,
                             RESEND_AFTER)
            if got is None:
                return {}
            return {name: parameter_value_to_python(value) for name, value in zip(names, got.values)}
        finally:
            self.node.destroy_client(lister)
            self.node.destroy_client(getter)

    def set_parameters(self, node: str, values: dict[str, Any], timeout: float,
                       check: Callable[[], None] = lambda: None) -> str | None:
        """Set parameters of ``/node`` through its service; None on success, else the reason."""
        client = self.node.create_client(SetParameters, f'/{node}/set_parameters')
        try:
            if not self.spin_until(client.service_is_ready, timeout, check):
                return f'/{node}/set_parameters did not become available in {timeout:g} s'
            if not prime(client, SetParameters.Request(),
                         lambda done, wait: self.spin_until(done, wait, check), timeout):
                return f'/{node}/set_parameters did not answer in {timeout:g} s'
            request = SetParameters.Request(
                parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
            response = self._call(client, request, timeout, check)
            if response is None:
                return f'/{node}/set_parameters did not answer in {timeout:g} s'
            failed = [r.reason for r in response.results if not r.successful]
            return '; '.join(failed) if failed else None
        finally:
            self.node.destroy_client(client)

    def publisher_count(self, topic: str) -> int:
        return self.node.count_publishers(topic)

    def _call(self, client: Any, request: Any, timeout: float, check: Callable[[], None],
              resend_after: float | None = None) -> Any:
        """The response, None without one in ``timeout`` s; ``resend_after`` [s] for a read
        (``nodes/services.py``: a response can be lost)."""
        future = answer(client, request, lambda done, wait: self.spin_until(done, wait, check),
                        timeout, resend_after)
        return None if future is None else future.result()

    def destroy(self) -> None:
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown()
