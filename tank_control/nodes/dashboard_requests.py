"""dashboard_node's page requests and service calls: a page's ``set`` (a parameter, checked
by the node's own validation, recorded on ``/parameter_audit``), ``command`` (a
``std_srvs/Trigger``) and ``preview`` (the tuning view's prediction, in a thread), answered
when the call's response comes or ``CALL_TIMEOUT`` passed. Taken from the web thread's queue by
the node's pump timer, in the executor's thread."""
from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from std_msgs.msg import String
from std_srvs.srv import Trigger

from tank_control.dashboard.robustness import tuning_preview
from tank_control.dashboard.server import Reply
from tank_control.dashboard.values import parse_text
from tank_control.nodes.dashboard_views import DashboardViews, NodeView, from_json
from tank_control.nodes.params import audit_record

#: How long a service call of the page may take before the page is told it had no answer [s].
CALL_TIMEOUT = 5.0
#: Most parameters one tuning-view preview may change.
MAX_PREVIEW_CHANGES = 8


@dataclass
class _Call:
    """A service call in flight: what to do with its response, or when none came in time."""

    client: Any
    future: Any
    deadline: float
    then: Callable[[Any], None]
    failed: Callable[[str], None]


def parameter_msg(name: str, value: Any, kind: int) -> ParameterMsg:
    """A ``rcl_interfaces/Parameter`` holding ``value`` (an empty list typed as ``kind``)."""
    if isinstance(value, list) and not value:
        return ParameterMsg(name=name, value=ParameterValue(type=kind))
    return Parameter(name, value=value).to_parameter_msg()


class DashboardRequests(DashboardViews):
    """The page's requests (``_requests``, filled by the web thread) and the service calls in
    flight (``_calls``); attributes set by ``DashboardNode.__init__``."""

    _requests: queue.SimpleQueue[tuple[dict[str, Any], Reply]]
    _calls: list[_Call]
    _preview_busy: threading.Lock
    _audit_pub: Publisher

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

    def _set(self, view: NodeView | None, node: str, name: str, text: str, request_id: Any,
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
            if ok and value != from_json(shown):   # who asked: the node's record cannot say
                self._audit_pub.publish(String(data=audit_record(
                    node, name, from_json(shown), value,
                    f'dashboard {self.get_fully_qualified_name()} (page at {peer})')))
            answer(ok, '' if ok else '; '.join(r.reason for r in results if not r.successful)
                   or 'refused without a reason')
        request = SetParameters.Request(parameters=[parameter_msg(name, value, kind)])
        self._call(view.clients['set'], request, then, lambda reason: answer(False, reason))

    def _command(self, view: NodeView | None, node: str, command: str, request_id: Any,
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

    def _preview(self, view: NodeView | None, node: str, changes: Any, request_id: Any,
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
            'controller') == from_json(view.params.get('controller', {}).get('value')) else None

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
