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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterEvent, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import qos_profile_parameter_events
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from tank_control.core.node_specs import is_ros_own
from tank_control.core.params import specs_of
from tank_control.core.stamps import FutureStamps
from tank_control.dashboard.access import Access, derive_read_only, origins_reason, start_token
from tank_control.dashboard.config import DashboardConfig
from tank_control.dashboard.robustness import RobustnessWorker, tuning_preview
from tank_control.dashboard.server import DashboardServer, Reply
from tank_control.dashboard.store import SampleStore
from tank_control.dashboard.values import jsonable, parse_text
from tank_control.nodes.clock import steady_clock
from tank_control.nodes.loop_performance import TOPIC as LOOP_PERFORMANCE_TOPIC
from tank_control.nodes.messages import (ORIGIN_QOS, TOPIC_DIAGNOSTICS, TOPIC_DISTURBANCE,
                                         TOPIC_MANIPULATED, TOPIC_MEASUREMENT, TOPIC_SETPOINT,
                                         TOPIC_TIME_ORIGIN, from_joint_state,
                                         reliable_qos, stamp_to_ns)
from tank_control.nodes.params import (AUDIT_QOS, AUDIT_TOPIC, ParameterBinding, ParameterError,
                                       audit_record)
from tank_control.nodes.runtime import main as run_node_main

#: The signal topics shown as trends.
SIGNAL_TOPICS = (TOPIC_MEASUREMENT, TOPIC_SETPOINT, TOPIC_MANIPULATED, TOPIC_DISTURBANCE)
#: Reliable (as published), deeper than the publishers' 10: a burst waits here, not lost.
DASHBOARD_SIGNAL_QOS = reliable_qos(100)
#: State changes kept for pages that connect later (marks on the trends).
MAX_MARKS = 200
#: A controller kind's state topic (std_msgs/String): reliable, transient local, keep-last 10.
STATE_QOS = reliable_qos(10, latched=True)
#: How long a service call of the page may take before the page is told it had no answer [s].
CALL_TIMEOUT = 5.0
#: Period of the timer that takes the page's requests and finished service calls [s].
PUMP_PERIOD = 0.02
#: wall: a signal sample stamped more than this many plant ticks (at least ``FUTURE_MIN_S``)
#: ahead of the dashboard's clock is not shown (``future.refused``): one would stretch the
#: trends' time axis past every valid sample. (sim/lockstep: not checked — a dashboard loses
#: messages when it lags, so no stamp it holds is its now.)
FUTURE_TICKS = 64
FUTURE_MIN_S = 1.0
NS_PER_S = 1_000_000_000
#: Audit records (/parameter_audit) kept for pages that connect later, and the longest taken
#: (characters; a longer one, from any publisher on the domain, is ignored and counted).
MAX_AUDIT = 200
MAX_AUDIT_CHARS = 1 << 20
#: Most parameters one tuning-view preview may change.
MAX_PREVIEW_CHANGES = 8
#: Fields of a node's /diagnostics status the page's faceplate shows (alarms, fail-safe).
FACEPLATE_FIELDS = frozenset({'mode', 'fault', 'saturated', 'stale_inputs', 'anti_windup_active'})
#: /diagnostics values shown by their prefix: each loop's verdict and indices (docs/monitoring.md).
FACEPLATE_PREFIXES = ('loop_performance.', 'loop_indices.')
#: Period of the look at the access counters (a change is published on /diagnostics) [s].
ACCESS_PERIOD = 1.0


@dataclass
class _Call:
    """A service call in flight: what to do with its response, or when none came in time."""

    client: Any
    future: Any
    deadline: float
    then: Callable[[Any], None]
    failed: Callable[[str], None]


@dataclass
class _NodeView:
    """What the page shows of one node: parameters, commands, state topics, diagnostics."""

    name: str                     # fully qualified, '/controller'
    clients: dict[str, Any] = field(default_factory=dict)
    params: dict[str, dict[str, Any]] = field(default_factory=dict)
    loaded: bool = False
    loading: bool = False
    commands: tuple[str, ...] = ()
    command_clients: dict[str, Any] = field(default_factory=dict)
    states: dict[str, str] = field(default_factory=dict)
    state_subs: dict[str, Any] = field(default_factory=dict)
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        return {'name': self.name, 'loaded': self.loaded, 'params': self.params,
                'commands': list(self.commands), 'states': dict(self.states),
                'diagnostics': self.diagnostics}


def _descriptor_json(desc: Any, value: ParameterValue) -> dict[str, Any]:
    """A parameter's descriptor and value as the page uses them."""
    out: dict[str, Any] = {
        'type': int(value.type), 'value': jsonable(parameter_value_to_python(value)),
        'description': desc.description, 'read_only': bool(desc.read_only),
        'constraints': desc.additional_constraints}
    if desc.floating_point_range:
        r = desc.floating_point_range[0]
        out['range'] = [jsonable(r.from_value), jsonable(r.to_value)]
    elif desc.integer_range:
        r = desc.integer_range[0]
        out['range'] = [r.from_value, r.to_value]
    return out


def parameter_msg(name: str, value: Any, kind: int) -> ParameterMsg:
    """A ``rcl_interfaces/Parameter`` holding ``value`` (an empty list typed as ``kind``)."""
    if isinstance(value, list) and not value:
        empty = ParameterValue(type=kind)
        return ParameterMsg(name=name, value=empty)
    return Parameter(name, value=value).to_parameter_msg()


class DashboardNode(Node):
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
        self._views: dict[str, _NodeView] = {}
        self._limits: dict[str, list[Any]] = {}
        self._units: dict[str, str] = {}          # channel -> unit, of the shown plant's kind
        self._origin_ns = 0
        self._requests: queue.SimpleQueue[tuple[dict[str, Any], Reply]] = queue.SimpleQueue()
        self._calls: list[_Call] = []
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

    # ------------------------------------------------------------ executor thread
    def _pump(self) -> None:
        while True:
            try:
                message, reply = self._requests.get_nowait()
            except queue.Empty:
                break
            try:
                self._handle(message, reply)
            except Exception as exc:     # noqa: BLE001 - no page's request may stop the node
                reply({'type': 'error', 'id': message.get('id'),
                       'reason': f'request not understood: {exc}'})
        now = time.monotonic()
        calls, self._calls = self._calls, []
        for call in calls:                # a continuation may start new calls: into _calls
            if call.future.done():
                try:
                    result = call.future.result()
                except Exception as exc:    # noqa: BLE001 - the page gets the reason
                    call.failed(str(exc))
                else:
                    call.then(result)
            elif now > call.deadline:
                call.client.remove_pending_request(call.future)
                call.failed(f'no answer within {CALL_TIMEOUT:g} s')
            else:
                self._calls.append(call)

    def _call(self, client: Any, request: Any, then: Callable[[Any], None],
              failed: Callable[[str], None]) -> None:
        if not client.service_is_ready():
            failed(f'{client.srv_name} is not available')
            return
        self._calls.append(_Call(client, client.call_async(request),
                                 time.monotonic() + CALL_TIMEOUT, then, failed))

    def _handle(self, message: dict[str, Any], reply: Reply) -> None:
        kind = message.get('type')
        node = str(message.get('node', ''))
        with self._lock:
            view = self._views.get(node)
        if kind == 'set':
            self._set(view, node, str(message['name']), str(message['text']),
                      message.get('id'), reply, str(message.get('peer', '?')))
        elif kind == 'command':
            self._command(view, node, str(message['command']), message.get('id'), reply)
        elif kind == 'preview':
            self._preview(view, node, message['changes'], message.get('id'), reply)
        else:
            raise ValueError(f'unknown request type {kind!r}')

    def _set(self, view: _NodeView | None, node: str, name: str, text: str, request_id: Any,
             reply: Reply, peer: str = '?') -> None:
        def answer(successful: bool, reason: str) -> None:
            reply({'type': 'set_result', 'id': request_id, 'node': node, 'name': name,
                   'successful': successful, 'reason': reason})
        if view is None or name not in view.params:
            answer(False, f'{node}: no parameter {name} (node not shown or gone)')
            return
        kind = int(view.params[name]['type'])
        value = parse_text(text, kind)
        shown = view.params[name]['value']

        def then(response: SetParameters.Response) -> None:
            results = list(response.results)
            ok = bool(results) and all(r.successful for r in results)
            if ok and value != _from_json(shown):   # who asked: the node's record cannot say
                self._audit_pub.publish(String(data=audit_record(
                    node, name, _from_json(shown), value,
                    f'dashboard {self.get_fully_qualified_name()} (page at {peer})')))
            answer(ok, '' if ok else '; '.join(r.reason for r in results if not r.successful)
                   or 'refused without a reason')
        request = SetParameters.Request(parameters=[parameter_msg(name, value, kind)])
        self._call(view.clients['set'], request, then, lambda reason: answer(False, reason))

    def _command(self, view: _NodeView | None, node: str, command: str, request_id: Any,
                 reply: Reply) -> None:
        def answer(success: bool, text: str) -> None:
            reply({'type': 'command_result', 'id': request_id, 'node': node,
                   'command': command, 'success': success, 'message': text})
        if view is None or command not in view.commands:
            answer(False, f'{node}: no command {command}')
            return
        client = view.command_clients.get(command)
        if client is None:
            client = view.command_clients[command] = self.create_client(
                Trigger, f'{node}/{command}')
        self._call(client, Trigger.Request(),
                   lambda response: answer(bool(response.success), response.message),
                   lambda reason: answer(False, reason))

    # ------------------------------------------------------------ discovery
    def _shown(self, name: str, namespace: str) -> bool:
        if name.startswith('_') or (name == self.get_name()
                                    and namespace == self.get_namespace()):
            return False
        return '*' in self._wanted or name in self._wanted

    def _discover(self) -> None:
        """Nodes come and go; a node's commands and state topics appear with it."""
        present = {}
        for name, namespace in self.get_node_names_and_namespaces():
            if self._shown(name, namespace):
                present[namespace.rstrip('/') + '/' + name] = (name, namespace)
        with self._lock:
            gone = [full for full in self._views if full not in present]
        for full in gone:
            self._drop(full)
        for full, (name, namespace) in sorted(present.items()):
            with self._lock:
                view = self._views.get(full)
            if view is None:
                view = self._add(full)
            if not view.loaded and not view.loading:
                self._load(view)
            self._look_at(view, name, namespace)

    def _add(self, full: str) -> _NodeView:
        view = _NodeView(full)
        for key, srv, suffix in (('list', ListParameters, 'list_parameters'),
                                 ('describe', DescribeParameters, 'describe_parameters'),
                                 ('get', GetParameters, 'get_parameters'),
                                 ('set', SetParameters, 'set_parameters')):
            view.clients[key] = self.create_client(srv, f'{full}/{suffix}')
        with self._lock:
            self._views[full] = view
        return view

    def _drop(self, full: str) -> None:
        with self._lock:
            view = self._views.pop(full)
        for client in [*view.clients.values(), *view.command_clients.values()]:
            self.destroy_client(client)
        for sub in view.state_subs.values():
            self.destroy_subscription(sub)
        self.server.broadcast({'type': 'node_gone', 'node': full})
        self._update_robustness()

    def _look_at(self, view: _NodeView, name: str, namespace: str) -> None:
        """The node's Trigger services (commands) and std_msgs/String topics (states)."""
        try:
            services = self.get_service_names_and_types_by_node(name, namespace)
            topics = self.get_publisher_names_and_types_by_node(name, namespace)
        except Exception:          # noqa: BLE001 - the node left between the two looks
            return
        prefix = view.name + '/'
        commands = tuple(sorted(s[len(prefix):] for s, types in services
                                if s.startswith(prefix) and 'std_srvs/srv/Trigger' in types))
        # a kind's state topic (e.g. autotune_state); the loop monitor's summaries are JSON,
        # shown through /diagnostics (loop_performance.<output>), not a state
        states = sorted(t for t, types in topics
                        if t.startswith(prefix) and 'std_msgs/msg/String' in types
                        and t != prefix + LOOP_PERFORMANCE_TOPIC.removeprefix('~/'))
        changed = commands != view.commands
        view.commands = commands
        for topic in states:
            if topic not in view.state_subs:
                view.state_subs[topic] = self.create_subscription(
                    String, topic, functools.partial(self._on_state, view, topic),
                    STATE_QOS)
                changed = True
        if changed and view.loaded:
            self._send_node(view)

    def _send_node(self, view: _NodeView) -> None:
        with self._lock:
            event = {'type': 'node', 'node': view.as_json()}
        self.server.broadcast(event)

    def _load(self, view: _NodeView) -> None:
        """list → describe and get → the node's parameter panel."""
        if not all(client.service_is_ready() for client in view.clients.values()):
            return            # its services are not matched yet: the next look tries again
        view.loading = True

        def failed(reason: str) -> None:
            view.loading = False
            self.get_logger().warning(f'{view.name}: parameters not read ({reason}); '
                                      'trying again')

        def listed(response: ListParameters.Response) -> None:
            names = list(response.result.names)
            state: dict[str, Any] = {}

            def both() -> None:
                if 'desc' in state and 'values' in state and 'primed' in state:
                    params = {n: _descriptor_json(d, v) for n, d, v
                              in zip(names, state['desc'], state['values'])}
                    with self._lock:
                        view.params = params
                        view.loaded, view.loading = True, False
                    self._update_limits(view)
                    self._update_units(view)
                    self._update_robustness()
                    self._send_node(view)

            def described(r: DescribeParameters.Response) -> None:
                state['desc'] = list(r.descriptors)
                both()

            def got(r: GetParameters.Response) -> None:
                state['values'] = list(r.values)
                both()
            self._call(view.clients['describe'], DescribeParameters.Request(names=names),
                       described, failed)
            self._call(view.clients['get'], GetParameters.Request(names=names), got, failed)
            # An empty set changes nothing; its answer shows the node matched the set
            # client's response reader, so a later set's answer is not lost
            # (nodes/services.py). Without it the panel is not shown yet: tried again.
            def primed(_: SetParameters.Response) -> None:
                state['primed'] = True
                both()
            self._call(view.clients['set'], SetParameters.Request(), primed, failed)
        self._call(view.clients['list'], ListParameters.Request(), listed, failed)

    # ------------------------------------------------------------ updates from the graph
    def _on_parameter_event(self, event: ParameterEvent) -> None:
        with self._lock:
            view = self._views.get(event.node)
        if view is None or not view.loaded:
            return
        if event.new_parameters or event.deleted_parameters:
            view.loaded = False           # declared or undeclared: read the node again
            self._load(view)
            return
        updates = []
        with self._lock:
            for param in event.changed_parameters:
                entry = view.params.get(param.name)
                if entry is None:
                    continue
                entry['value'] = jsonable(parameter_value_to_python(param.value))
                entry['type'] = int(param.value.type)
                updates.append({'type': 'param', 'node': view.name, 'name': param.name,
                                'value': entry['value'], 'ptype': entry['type']})
        for update in updates:
            self.server.broadcast(update)
        changed = {update['name'] for update in updates}
        for name in sorted(changed):
            machine, _, field = name.rpartition('.')
            if field == 'state':
                self._mark(view, machine, timed=f'{machine}.state_time' in changed)
            elif field == 'state_time' and f'{machine}.state' not in changed:
                self._mark(view, machine, timed=True, update=True)
        if updates:
            self._update_limits(view)
            self._update_robustness()

    def _mark(self, view: _NodeView, machine: str, timed: bool, update: bool = False) -> None:
        """A state machine's change (``<machine>.state``, e.g. the relay auto-tuner's) as a mark
        on the trends at ``<machine>.state_time`` (the loop time in s of the first sample in
        the state) when ``timed``; a state entered by a command is written before that sample,
        so it is marked at the newest sample time seen and moved (``update``) when its
        ``state_time`` comes."""
        with self._lock:
            entry_t = view.params.get(f'{machine}.state_time')
            entry_state = view.params.get(f'{machine}.state')
            if entry_t is None or entry_state is None:
                return
            t = entry_t['value'] if timed or not math.isfinite(self._latest_t) else self._latest_t
            mark = {'node': view.name, 'machine': machine, 't': t,
                    'label': str(entry_state['value']), 'update': update}
            last = next((m for m in reversed(self.marks) if m['node'] == view.name
                         and m['machine'] == machine), None)
            if update:
                if last is None or last['label'] != mark['label']:
                    return
                last['t'] = t
            else:
                self.marks.append({k: v for k, v in mark.items() if k != 'update'})
                del self.marks[:-MAX_MARKS]
        self.server.broadcast({'type': 'mark', **mark})

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

    def _on_state(self, view: _NodeView, topic: str, msg: String) -> None:
        with self._lock:
            view.states[topic] = msg.data
        self.server.broadcast({'type': 'state', 'node': view.name, 'topic': topic,
                               'value': msg.data})

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            prefix = status.name.split(':', 1)[0].strip()
            with self._lock:
                views = [v for v in self._views.values() if v.name.rsplit('/', 1)[-1] == prefix]
                info = {'level': int.from_bytes(status.level, 'little')
                        if isinstance(status.level, bytes) else int(status.level),
                        'message': status.message,
                        'fields': {kv.key: kv.value[:200] for kv in status.values[:200]
                                   if kv.key in FACEPLATE_FIELDS
                                   or kv.key.startswith(FACEPLATE_PREFIXES)}}
                for view in views:
                    view.diagnostics = info
            for view in views:
                self.server.broadcast({'type': 'diagnostics', 'node': view.name, **info})

    def _update_units(self, view: _NodeView) -> None:
        """The channels' units of a plant node (its kind's ``units``), for the page."""
        from tank_control.core.plants.kinds import registry
        with self._lock:
            entry = view.params.get('plant')
        if entry is None:
            return
        try:
            units = dict(registry.get_kind(str(entry['value'])).units)
        except (ValueError, KeyError, TypeError):
            return
        with self._lock:
            if units == self._units:
                return
            self._units = units
        self.server.broadcast({'type': 'units', 'units': units})

    def _update_limits(self, view: _NodeView) -> None:
        """Input limits {channel: [min, max]} of a controller node, through its kind."""
        from tank_control.core.scenario import controller_setup
        with self._lock:
            values = {name: entry['value'] for name, entry in view.params.items()}
        if 'controller' not in values:
            return
        try:
            setup = controller_setup({k: _from_json(v) for k, v in values.items()
                                      if not is_ros_own(k)}, given=())
            kind = setup.kind
            limits = dict(kind.input_limits(setup.settings)) if kind.input_limits else {}
        except (ValueError, KeyError, TypeError):
            return
        table = {name: [jsonable(float(lo)), jsonable(float(hi))]
                 for name, (lo, hi) in limits.items()}
        with self._lock:
            if table == self._limits:
                return
            self._limits = table
        self.server.broadcast({'type': 'limits', 'limits': table})

    def _loop_values(self) -> dict[str, dict[str, Any]]:
        """Parameter values of the shown plant and controller nodes (role -> values)."""
        found: dict[str, dict[str, Any]] = {}
        with self._lock:
            for view in self._views.values():
                if not view.loaded:
                    continue
                for role in ('controller', 'plant'):
                    if role in view.params and role not in found:
                        found[role] = {k: _from_json(e['value']) for k, e in view.params.items()
                                       if not is_ros_own(k)}
                        break
        return found

    def _preview(self, view: _NodeView | None, node: str, changes: Any, request_id: Any,
                 reply: Reply) -> None:
        """The tuning view's prediction for ``changes`` ({name: text}) of a controller, computed
        in a thread of its own (``robustness.tuning_preview``); nothing is set."""
        def answer(result: dict[str, Any]) -> None:
            reply({'type': 'preview_result', 'id': request_id, 'node': node, **result})
        if view is None or not isinstance(changes, dict) or len(changes) > MAX_PREVIEW_CHANGES:
            answer({'available': False, 'reason': f'{node}: not a controller shown here, or '
                    f'not {{name: text}} of at most {MAX_PREVIEW_CHANGES} changes'})
            return
        values: dict[str, Any] = {}
        for name, text in changes.items():
            entry = view.params.get(str(name))
            if entry is None:
                answer({'available': False, 'reason': f'{node}: no parameter {name}'})
                return
            try:
                values[str(name)] = parse_text(str(text), int(entry['type']))
            except ValueError as exc:
                answer({'available': False, 'reason': f'{name}: {exc}'})
                return
        found = self._loop_values()
        controller = found.get('controller') if found.get('controller', {}).get(
            'controller') == _from_json(view.params.get('controller', {}).get('value')) else None

        if not self._preview_busy.acquire(blocking=False):     # one at a time (CPU)
            answer({'available': False, 'reason': 'busy: another preview is being computed; '
                    'try again'})
            return

        def work() -> None:
            try:
                result = tuning_preview(found.get('plant'), controller, values)
            except Exception as exc:     # noqa: BLE001 - the page gets the reason
                result = {'available': False, 'reason': f'no prediction: {exc}'}
            finally:
                self._preview_busy.release()
            answer(result)
        threading.Thread(target=work, name='dashboard-preview', daemon=True).start()

    def _update_robustness(self) -> None:
        """Bode, Nyquist and margins of the loop of the shown plant and controller nodes
        (the nodes with a ``plant`` / ``controller`` kind parameter), recomputed in the
        worker's thread when their values changed (``dashboard/robustness.py``)."""
        found = self._loop_values()
        self.robustness.submit(found.get('plant'), found.get('controller'))
        ts = (found.get('plant') or {}).get('sample_time')
        if isinstance(ts, (int, float)) and ts > 0:
            self.future.tolerance_ns = max(int(FUTURE_TICKS * ts * 1e9), int(FUTURE_MIN_S * 1e9))


def _from_json(value: Any) -> Any:
    """A page value back to Python (non-finite doubles travel as strings)."""
    if value in ('inf', '-inf', 'nan'):
        return float(value)
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    return value


def main(args: list[str] | None = None) -> int:
    """Console entry point dashboard_node; exit 2 with a one-line reason on bad parameters
    or a port that cannot be listened on."""
    return run_node_main('dashboard_node', DashboardNode, args)


if __name__ == '__main__':
    sys.exit(main())
