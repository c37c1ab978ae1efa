"""dashboard_node's view of the graph: the nodes it shows (their parameters, commands, state
topics and diagnostics), found and read through their services, kept current from
``/parameter_events``, and what the page derives from them (input limits, units, the loop's
robustness). The node class (``dashboard_node.DashboardNode``) wires it; everything here runs
in the executor's thread, the page reads it under ``_lock``."""
from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterEvent, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from std_msgs.msg import String

from tank_control.core.node_specs import is_ros_own
from tank_control.core.stamps import FutureStamps
from tank_control.dashboard.robustness import RobustnessWorker
from tank_control.dashboard.server import DashboardServer
from tank_control.dashboard.values import jsonable
from tank_control.nodes.loop_performance import MODE_TOPIC, TOPIC as LOOP_PERFORMANCE_TOPIC
from tank_control.nodes.messages import reliable_qos

#: State changes kept for pages that connect later (marks on the trends).
MAX_MARKS = 200
#: A controller kind's state topic (std_msgs/String): reliable, transient local, keep-last 10.
STATE_QOS = reliable_qos(10, latched=True)
#: wall: a signal sample stamped more than this many plant ticks (at least ``FUTURE_MIN_S``)
#: ahead of the dashboard's clock is not shown (``future.refused``): one would stretch the
#: trends' time axis past every valid sample. (sim/lockstep: not checked — a dashboard loses
#: messages when it lags, so no stamp it holds is its now.)
FUTURE_TICKS = 64
FUTURE_MIN_S = 1.0
#: The loop monitor's topics of a controller (JSON, not a kind's state topic).
MONITOR_TOPICS = frozenset(t.removeprefix('~/') for t in (LOOP_PERFORMANCE_TOPIC, MODE_TOPIC))
#: Fields of a node's /diagnostics status the page's faceplate shows (alarms, fail-safe).
FACEPLATE_FIELDS = frozenset({'mode', 'fault', 'saturated', 'stale_inputs', 'anti_windup_active'})
#: /diagnostics values shown by their prefix: each loop's verdict and indices (docs/monitoring.md).
FACEPLATE_PREFIXES = ('loop_performance.', 'loop_indices.')


@dataclass
class NodeView:
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


def from_json(value: Any) -> Any:
    """A page value back to Python (non-finite doubles travel as strings)."""
    if value in ('inf', '-inf', 'nan'):
        return float(value)
    if isinstance(value, list):
        return [from_json(v) for v in value]
    return value


class DashboardViews(Node):
    """The shown nodes (``_views``) and what is derived from them; the attributes below are
    set by ``DashboardNode.__init__``."""

    _lock: threading.Lock
    _views: dict[str, NodeView]
    _wanted: tuple[str, ...]
    _limits: dict[str, list[Any]]
    _units: dict[str, str]
    _latest_t: float
    marks: list[dict[str, Any]]
    future: FutureStamps
    robustness: RobustnessWorker
    server: DashboardServer

    def _call(self, client: Any, request: Any, then: Callable[[Any], None],
              failed: Callable[[str], None]) -> None:
        raise NotImplementedError        # dashboard_requests.DashboardRequests

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

    def _add(self, full: str) -> NodeView:
        view = NodeView(full)
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

    def _look_at(self, view: NodeView, name: str, namespace: str) -> None:
        """The node's Trigger services (commands) and std_msgs/String topics (states)."""
        try:
            services = self.get_service_names_and_types_by_node(name, namespace)
            topics = self.get_publisher_names_and_types_by_node(name, namespace)
        except Exception:          # noqa: BLE001 - the node left between the two looks
            return
        prefix = view.name + '/'
        commands = tuple(sorted(s[len(prefix):] for s, types in services
                                if s.startswith(prefix) and 'std_srvs/srv/Trigger' in types))
        # a kind's state topic (e.g. autotune_state); the loop monitor's summaries and mode
        # log are JSON, shown through /diagnostics (loop_performance.<output>), not states
        states = sorted(t for t, types in topics
                        if t.startswith(prefix) and 'std_msgs/msg/String' in types
                        and t[len(prefix):] not in MONITOR_TOPICS)
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

    def _send_node(self, view: NodeView) -> None:
        with self._lock:
            event = {'type': 'node', 'node': view.as_json()}
        self.server.broadcast(event)

    def _load(self, view: NodeView) -> None:
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

    def _mark(self, view: NodeView, machine: str, timed: bool, update: bool = False) -> None:
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

    def _on_state(self, view: NodeView, topic: str, msg: String) -> None:
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

    def _update_units(self, view: NodeView) -> None:
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

    def _update_limits(self, view: NodeView) -> None:
        """Input limits {channel: [min, max]} of a controller node, through its kind."""
        from tank_control.core.scenario import controller_setup
        with self._lock:
            values = {name: entry['value'] for name, entry in view.params.items()}
        if 'controller' not in values:
            return
        try:
            setup = controller_setup({k: from_json(v) for k, v in values.items()
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
                        found[role] = {k: from_json(e['value']) for k, e in view.params.items()
                                       if not is_ros_own(k)}
                        break
        return found

    def _update_robustness(self) -> None:
        """Bode, Nyquist and margins of the loop of the shown plant and controller nodes
        (the nodes with a ``plant`` / ``controller`` kind parameter), recomputed in the
        worker's thread when their values changed (``dashboard/robustness.py``)."""
        found = self._loop_values()
        self.robustness.submit(found.get('plant'), found.get('controller'))
        ts = (found.get('plant') or {}).get('sample_time')
        if isinstance(ts, (int, float)) and ts > 0:
            self.future.tolerance_ns = max(int(FUTURE_TICKS * ts * 1e9), int(FUTURE_MIN_S * 1e9))
