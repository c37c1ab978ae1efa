"""dashboard_node: a live web page to watch and steer a running loop (docs/dashboard.md).

Subscribes the signal topics (``measurement``, ``setpoint``, ``manipulated``, ``disturbance``),
``time_origin``, ``/parameter_events``, ``/diagnostics`` and the state topics of the nodes it
shows; calls their parameter services (list, describe, get, set) and their ``std_srvs/Trigger``
commands. Publishes nothing on the loop's topics, so it cannot disturb the loop. The web server
(``tank_control/dashboard/server.py``) runs in a thread of its own; everything rclpy happens
here, in the executor's thread: the page's requests are taken from a queue by a timer. Times in
s of plant time (stamp − the plant's ``time_origin``).
"""
from __future__ import annotations

import functools
import json
import math
import os
import queue
import sys
import threading
import time
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterEvent
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.qos import qos_profile_parameter_events
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from tank_control.core.params import specs_of
from tank_control.core.stamps import FutureStamps
from tank_control.dashboard.access import Access, derive_read_only, origins_reason, start_token
from tank_control.dashboard.config import DashboardConfig
from tank_control.dashboard.robustness import RobustnessWorker
from tank_control.dashboard.server import DashboardServer, Reply
from tank_control.dashboard.store import SampleStore
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.dashboard_requests import DashboardRequests
from tank_control.nodes.dashboard_views import FUTURE_MIN_S, NodeView
from tank_control.nodes.messages import (ORIGIN_QOS, TOPIC_DIAGNOSTICS, TOPIC_DISTURBANCE,
                                         TOPIC_MANIPULATED, TOPIC_MEASUREMENT, TOPIC_SETPOINT,
                                         TOPIC_TIME_ORIGIN, from_joint_state,
                                         reliable_qos, stamp_to_ns)
from tank_control.nodes.params import AUDIT_QOS, AUDIT_TOPIC, ParameterBinding, ParameterError
from tank_control.nodes.runtime import main as run_node_main

#: The signal topics shown as trends.
SIGNAL_TOPICS = (TOPIC_MEASUREMENT, TOPIC_SETPOINT, TOPIC_MANIPULATED, TOPIC_DISTURBANCE)
#: Reliable (as published), deeper than the publishers' 10: a burst waits here, not lost.
DASHBOARD_SIGNAL_QOS = reliable_qos(100)
#: Period of the timer that takes the page's requests and finished service calls [s].
PUMP_PERIOD = 0.02
NS_PER_S = 1_000_000_000
#: Audit records (/parameter_audit) kept for pages that connect later, and the longest taken
#: (characters; a longer one, from any publisher on the domain, is ignored and counted).
MAX_AUDIT = 200
MAX_AUDIT_CHARS = 1 << 20
#: Period of the look at the access counters (a change is published on /diagnostics) [s].
ACCESS_PERIOD = 1.0


class DashboardNode(DashboardRequests):
    """Signals → sample store → pages; pages' requests → parameter services and commands."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('dashboard', **kwargs)
        self._params = ParameterBinding(
            self, specs_of(DashboardConfig), derive=derive_read_only,
            cross_check=lambda values, _: origins_reason(values['allowed_origins']))
        values = self._params.values
        try:
            token = start_token(os.environ)
        except ValueError as exc:
            raise ParameterError(str(exc)) from None
        self.access = Access(values['allowed_origins'], bool(values['read_only']),
                             self.get_logger().warning, token)
        self._wanted = tuple(values['nodes'])
        self._lock = threading.Lock()            # the views, the limits and the origin
        self._views: dict[str, NodeView] = {}
        self._limits: dict[str, list[Any]] = {}
        self._units: dict[str, str] = {}          # channel -> unit, of the shown plant's kind
        self._origin_ns = 0
        self._requests: queue.SimpleQueue[tuple[dict[str, Any], Reply]] = queue.SimpleQueue()
        self._calls = []
        self._preview_busy = threading.Lock()     # a tuning-view preview is being computed
        self.received = {topic: 0 for topic in SIGNAL_TOPICS}
        self.ignored = 0
        self.store = SampleStore(int(values['buffer_messages']))
        self.missed = {topic: 0 for topic in SIGNAL_TOPICS}
        self.marks: list[dict[str, Any]] = []     # state changes of the controllers' machines
        self.audit: list[dict[str, Any]] = []     # /parameter_audit records, oldest first
        self._latest_t = -math.inf                # plant time [s] of the newest signal sample
        self.future = FutureStamps(int(FUTURE_MIN_S * 1e9))   # tolerance: _update_robustness
        for topic in SIGNAL_TOPICS:
            self.create_subscription(JointState, topic,
                                     functools.partial(self._on_signal, topic),
                                     DASHBOARD_SIGNAL_QOS,
                                     event_callbacks=SubscriptionEventCallbacks(
                                         message_lost=functools.partial(self._on_lost, topic),
                                         use_default_callbacks=False))
        self.create_subscription(Time, TOPIC_TIME_ORIGIN, self._on_origin, ORIGIN_QOS)
        self.create_subscription(ParameterEvent, '/parameter_events', self._on_parameter_event,
                                 qos_profile_parameter_events)
        self.create_subscription(DiagnosticArray, TOPIC_DIAGNOSTICS, self._on_diagnostics, 10)
        self.create_subscription(String, AUDIT_TOPIC, self._on_audit, AUDIT_QOS)
        self._audit_pub = self.create_publisher(String, AUDIT_TOPIC, AUDIT_QOS)
        self._diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10)
        self.robustness = RobustnessWorker(lambda message: self.server.broadcast(message))
        self.server = DashboardServer(self.store, self, str(values['host']), int(values['port']),
                                      float(values['update_period']),
                                      str(values['runs_dir']), self.access)
        try:
            self.url = self.server.start()
        except OSError as exc:
            self.robustness.stop()
            raise ParameterError(f'host/port: {exc}') from None
        self.create_timer(PUMP_PERIOD, self._pump, clock=steady_clock())
        self.create_timer(float(values['discovery_period']), self._discover,
                          clock=steady_clock())
        self.create_timer(ACCESS_PERIOD, self._publish_access, clock=steady_clock())
        # the URL with this start's token, as a notebook server logs it: whoever opens it may
        # write (unless read_only); the page without it shows the loop read-only
        shown = self.url if self.access.read_only else f'{self.url}?token={self.access.token}'
        self.get_logger().info(f'dashboard at {shown} (nodes: {", ".join(self._wanted)}'
                               f'{"; read-only" if self.access.read_only else ""})')
        self._discover()

    def destroy_node(self) -> None:
        self.robustness.stop()
        self.server.stop()
        super().destroy_node()

    # ------------------------------------------------------------ signals
    def _on_signal(self, topic: str, msg: JointState) -> None:
        try:
            t_ns, names, values = from_joint_state(msg)
        except ValueError:
            self.ignored += 1
            return
        if self._origin_ns and not self.future.admit(topic, t_ns, time.time_ns(),
                                                     time.monotonic_ns()):
            for line in self.future.take_report():
                self.get_logger().warning(line + ' (not shown)')
            return
        self.received[topic] += 1
        t = (t_ns - self._origin_ns) / NS_PER_S
        self._latest_t = max(self._latest_t, t)
        self.store.add(topic, t, names, values)

    def _on_lost(self, topic: str, info: Any) -> None:
        """The middleware's message-lost event (``info``: QoSMessageLostInfo): messages of
        ``topic`` were published but never reached this node (the publishers keep the last 10
        for a reader that lags: a starved dashboard process). Counted and shown on the page as
        "missed", never silent."""
        count = int(info.total_count_change)
        with self._lock:
            self.missed[topic] += count
            missed = dict(self.missed)
        self.server.broadcast({'type': 'missed', 'missed': missed})

    def _on_origin(self, msg: Time) -> None:
        origin = stamp_to_ns(msg)
        with self._lock:
            if origin == self._origin_ns:
                return
            self._origin_ns = origin
        self.server.broadcast({'type': 'origin', 'origin': origin / NS_PER_S})

    # ------------------------------------------------------------ page requests (any thread)
    def snapshot(self) -> dict[str, Any]:
        """The graph as the page starts from (called by the web thread)."""
        with self._lock:
            return {'nodes': {name: view.as_json() for name, view in self._views.items()},
                    'limits': dict(self._limits), 'units': dict(self._units), 'origin': self._origin_ns / NS_PER_S,
                    'topics': list(SIGNAL_TOPICS), 'robustness': self.robustness.latest,
                    'missed': dict(self.missed), 'marks': list(self.marks),
                    'audit': list(self.audit)}

    def request(self, message: dict[str, Any], reply: Reply) -> None:
        """A page's request (web thread): handled by the next pump in the executor thread."""
        self._requests.put((message, reply))

    def _on_audit(self, msg: String) -> None:
        """A parameter change some node applied (nodes/params.py): kept and shown."""
        try:
            record = json.loads(msg.data) if len(msg.data) <= MAX_AUDIT_CHARS else None
        except ValueError:
            record = None
        if not isinstance(record, dict) or not isinstance(record.get('time'), (int, float)):
            self.ignored += 1
            return
        record = {key: record.get(key) for key in ('time', 'node', 'name', 'old', 'new',
                                                   'source')}
        with self._lock:
            self.audit.append(record)
            del self.audit[:-MAX_AUDIT]
        self.server.broadcast({'type': 'audit', 'record': record})

    def _publish_access(self) -> None:
        """What it refused on /diagnostics every period once there is something (as
        diagnostic_updater does, for a monitor that starts later): WARN, the requests refused
        (dashboard/access.py) by kind with the last reason, and the signal samples stamped in
        the future that are not shown (``rejected_future``)."""
        counts = self.access.counts()
        future = self.future.refused
        if not counts and not future:
            return
        total = sum(counts.values())
        parts = ([f'refused {total} requests ({self.access.last_reason})'] if counts else []) + (
            [f'{future} signal samples stamped in the future not shown'] if future else [])
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN, name=f'{self.get_name()}: access',
            message='; '.join(parts), hardware_id=self.url,
            values=[KeyValue(key=f'refused_{kind}', value=str(n))
                    for kind, n in sorted(counts.items())]
            + [KeyValue(key='rejected_future', value=str(future))])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Console entry point dashboard_node; exit 2 with a one-line reason on bad parameters
    or a port that cannot be listened on."""
    return run_node_main('dashboard_node', DashboardNode, args)


if __name__ == '__main__':
    sys.exit(main())
