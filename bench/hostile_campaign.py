"""A hostile user against a running graph (issue 30 re-run): parameters, messages, the dashboard's
WebSocket, OPC UA writes — every node must stay alive, keep its loop going and refuse what is bad.

Starts, in a ROS_DOMAIN_ID of its own (LOCALHOST), config/ipdt_pid.yaml's plant (wall mode,
serving its channels over OPC UA), controller and reference, a dashboard_node (a known token),
and an opcua_bridge_node in namespace /b connected to the plant's OPC UA server. Then:

* ``params``: every parameter of every node, through its ``set_parameters`` service (as
  ``ros2 param set`` does), with hostile values of its own type (NaN, ±inf, ±1e308, ±5e-324,
  1e-320, 0, −1, 2^63−1, …; lists: empty, [NaN], [1e308]×3, [5e-324], [−1], wrong lengths) and of
  the wrong types; an accepted value is set back to the original at once;
* ``dashboard``: foreign Origin, rebinding Host, no / wrong token, malformed JSON, a 2 MiB frame,
  then a ``set`` of every parameter of every shown node with hostile texts (with the token);
* ``topics``: each subscribed topic (measurement, setpoint, manipulated, disturbance,
  /b/manipulated, time_origin, /parameter_audit) with messages stamped +10 s, +1e6 s, in 2038
  (the largest int32 second),
  names and positions of different lengths, 100 000 names, NaN, inf, 1e308, no channels;
* ``opcua``: an OPC UA client writes NaN, ±inf, 1e308, a string, a bool, a huge Int64 to the
  plant's writable input;
* ``server``: a hostile OPC UA server behind a second bridge (/c) serves NaN, inf, 1e308, a
  string, a bool, UInt64 max, Bad and Uncertain statuses, SourceTimestamps in 2100, +10 s,
  1970, −10 s and none (3 samples each): what the bridge publishes must be finite, not stamped
  ahead, and go on after.

After each attack: every process alive, its parameter service answering (else a "freeze"); at
the end of each phase the loop still runs (``measurement`` comes, finite) and the controller's
output is finite. Prints a table of the figures (JSON with ``--json``).

    PYTHONPATH=$PWD .venv/bin/python bench/hostile_campaign.py [--phases params dashboard topics opcua]
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
TOKEN = 'hostile-campaign-token-0123456789'

FLOATS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -5e-324, 1e-320, 0.0, -1.0,
          1e154, -1e-300]
INTS = [0, -1, 2 ** 63 - 1, -2 ** 63, 2 ** 31, 10 ** 9]
STRINGS = ['', 'x' * 100_000, 'nan', '\u00e9\u0000', '../../etc/passwd']
FLOAT_LISTS = [[], [math.nan], [1e308] * 3, [5e-324], [-1.0], [math.inf, 0.0], [0.0] * 1000,
               [-5e-324, 1e-320]]
TEXTS_BY_TYPE = {
    3: ['nan', 'inf', '-inf', '1e308', '-1e308', '5e-324', '-5e-324', '1e400', '0', '-1', 'abc',
        '', '[1,2]'],
    2: ['0', '-1', '9223372036854775807', '-9223372036854775809', '1' + '0' * 30, '1e999', 'nan',
        'x'],
    1: ['maybe', '2', ''],
    4: ['', 'x' * 10000, 'nan', '"quoted"'],
    8: ['[]', '[NaN]', '[Infinity]', '[1e308, 1e308, 1e308]', '[5e-324]', '[-1]',
        '[1' + '0' * 400 + ']', '[null]', '[{"a": 1}]', '[' + '1,' * 5000 + '1]', 'nan, 1'],
    7: ['[]', '[1' + '0' * 30 + ']', '[[1]]', '[-1]', '[1e999]'],
    9: ['[]', '["x"]', '[1, null]', '["' + 'y' * 10000 + '"]'],
    6: ['[]', '[2]', '[true, "x"]'],
}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return int(s.getsockname()[1])


class Graph:
    """The processes of the attacked graph, each logging to a file."""

    def __init__(self, tmp: Path, domain: int) -> None:
        self.tmp = tmp
        self.env = {**os.environ, 'ROS_DOMAIN_ID': str(domain), 'PYTHONUNBUFFERED': '1',
                    'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
                    'TANK_CONTROL_DASHBOARD_TOKEN': TOKEN}
        self.procs: dict[str, subprocess.Popen] = {}
        self.opc_port = free_port()
        self.web_port = free_port()
        self.endpoint = f'opc.tcp://127.0.0.1:{self.opc_port}/tank'

    def start(self) -> None:
        cfg = str(REPO / 'config' / 'ipdt_pid.yaml')
        wall = ['-p', 'clock_mode:=wall']
        self._start('plant', 'plant_node', ['--params-file', cfg, *wall,
                                            '-p', f'opcua.endpoint:={self.endpoint}'])
        self._start('controller', 'controller_node', ['--params-file', cfg, *wall])
        self._start('reference', 'reference_node', ['--params-file', cfg, *wall])
        self._start('dashboard', 'dashboard_node', [
            '-p', f'port:={self.web_port}', '-p', "nodes:=['plant', 'controller', 'reference', "
            "'opcua_bridge']"])

    def start_bridge(self) -> None:
        params = self.tmp / 'bridge.yaml'
        params.write_text(json.dumps({'/**': {'ros__parameters': {
            'endpoint': self.endpoint, 'sample_time': 0.1, 'measurement.channels': ['y'],
            'measurement.y.node_id': 'ns=2;s=Plant.y', 'manipulated.channels': ['u'],
            'manipulated.u.node_id': 'ns=2;s=Plant.u', 'range.u': [-100.0, 100.0]}}}))
        self._start('opcua_bridge', 'opcua_bridge_node', ['-r', '__ns:=/b', '--params-file',
                                                          str(params)])

    def _start(self, name: str, module: str, args: list[str]) -> None:
        log = open(self.tmp / f'{name}.log', 'w')   # noqa: SIM115 (the process keeps it)
        self.procs[name] = subprocess.Popen(
            [sys.executable, '-m', f'tank_control.nodes.{module}', '--ros-args', *args],
            stdout=log, stderr=subprocess.STDOUT, env=self.env, cwd=str(self.tmp))  # PYTHONPATH

    def dead(self) -> list[str]:
        return [f'{n} (rc {p.returncode})' for n, p in self.procs.items() if p.poll() is not None]

    def log(self, name: str) -> str:
        return (self.tmp / f'{name}.log').read_text(errors='replace')

    def stop(self) -> None:
        for proc in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in self.procs.values():
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


class Probe:
    """The attacker's ROS node: parameter clients, publishers, the loop's signals."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        rclpy.init()
        self.rclpy = rclpy
        self.node = rclpy.create_node('hostile_probe')
        self.y: list[tuple[float, float]] = []
        self.u: list[tuple[float, float]] = []
        self.diag: dict[str, dict[str, str]] = {}
        self.node.create_subscription(JointState, 'measurement', lambda m: self.y.append(
            (time.monotonic(), m.position[0] if len(m.position) else math.nan)), 50)
        self.node.create_subscription(JointState, 'manipulated', lambda m: self.u.append(
            (time.monotonic(), m.position[0] if len(m.position) else math.nan)), 50)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.clients: dict[str, tuple[Any, Any, Any, Any]] = {}

    def _on_diag(self, msg: Any) -> None:
        for status in msg.status:
            key = status.name + (f' {status.hardware_id}' if status.name == 'opcua_bridge'
                                 else '')
            self.diag[key] = {kv.key: kv.value for kv in status.values}
            self.diag[key]['_level'] = str(status.level)

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.rclpy.spin_once(self.node, timeout_sec=min(0.05, max(0.0, end - time.monotonic())))

    def wait(self, condition: Any, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > end:
                return False
            self.rclpy.spin_once(self.node, timeout_sec=0.05)
        return True

    def call(self, client: Any, request: Any, timeout: float = 10.0) -> Any:
        if not client.wait_for_service(timeout_sec=timeout):
            return None
        future = client.call_async(request)
        if not self.wait(future.done, timeout):
            client.remove_pending_request(future)
            return None
        return future.result()

    def params_of(self, full: str) -> dict[str, Any]:
        """{name: ParameterValue} of node ``full``."""
        from rcl_interfaces.srv import GetParameters, ListParameters, SetParameters
        if full not in self.clients:
            self.clients[full] = (self.node.create_client(ListParameters, f'{full}/list_parameters'),
                                  self.node.create_client(GetParameters, f'{full}/get_parameters'),
                                  self.node.create_client(SetParameters, f'{full}/set_parameters'),
                                  None)
        lister, getter, _, _ = self.clients[full]
        names = self.call(lister, ListParameters.Request(depth=0), 30)
        assert names is not None, f'{full}: list_parameters does not answer'
        names = [n for n in names.result.names if not n.startswith('qos_overrides')]
        values = self.call(getter, GetParameters.Request(names=names), 30)
        return dict(zip(names, values.values))

    def set(self, full: str, msg: Any) -> tuple[bool | None, str]:
        """(successful, reason) of one set; (None, '') when the node does not answer."""
        from rcl_interfaces.srv import SetParameters
        result = self.call(self.clients[full][2], SetParameters.Request(parameters=[msg]))
        if result is None:
            return None, ''
        return bool(result.results[0].successful), result.results[0].reason

    def loop_runs(self, seconds: float = 2.0) -> tuple[bool, str]:
        """``measurement`` keeps coming (finite) and ``manipulated`` is finite."""
        t0 = time.monotonic()
        self.wait(lambda: len([1 for t, _ in self.y if t > t0]) >= 5, 10 + seconds)
        ys = [v for t, v in self.y if t > t0]
        us = [v for t, v in self.u if t > t0]
        if len(ys) < 5:
            return False, f'{len(ys)} measurements in {time.monotonic() - t0:.1f} s'
        if not all(math.isfinite(v) for v in ys + us):
            return False, 'a non-finite y or u'
        return True, f'{len(ys)} y, {len(us)} u'


def value_msg(value: Any) -> Any:
    from rcl_interfaces.msg import ParameterType, ParameterValue
    pv = ParameterValue()
    if isinstance(value, bool):
        pv.type, pv.bool_value = ParameterType.PARAMETER_BOOL, value
    elif isinstance(value, int):
        pv.type, pv.integer_value = ParameterType.PARAMETER_INTEGER, value
    elif isinstance(value, float):
        pv.type, pv.double_value = ParameterType.PARAMETER_DOUBLE, value
    elif isinstance(value, str):
        pv.type, pv.string_value = ParameterType.PARAMETER_STRING, value
    elif isinstance(value, list) and all(isinstance(v, str) for v in value) and value:
        pv.type, pv.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, value
    elif isinstance(value, list):
        pv.type, pv.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, value
    return pv


def hostile_values(pv: Any) -> list[Any]:
    """Values of the parameter's own type, then of wrong types."""
    own = {1: [True, False], 2: INTS, 3: FLOATS, 4: STRINGS, 8: FLOAT_LISTS,
           9: [['x'], ['y'] * 300, ['']], 7: [[2 ** 63 - 1]], 6: [[True]]}.get(pv.type, [])
    wrong = [1.5, 7, 'text', True, [math.nan], ['a', 'b']]
    return own + [w for w in wrong if value_msg(w).type != pv.type]


def phase_params(graph: Graph, probe: Probe, figures: dict[str, Any]) -> None:
    from rcl_interfaces.msg import Parameter
    for full in ('/controller', '/plant', '/reference', '/dashboard', '/b/opcua_bridge'):
        row = figures.setdefault(f'params {full}', {'sets': 0, 'refused': 0, 'accepted': 0,
                                                    'no answer': 0, 'refused without reason': 0})
        original = probe.params_of(full)
        for name, pv in original.items():
            if name == 'use_sim_time':
                continue
            for value in hostile_values(pv):
                row['sets'] += 1
                ok, reason = probe.set(full, Parameter(name=name, value=value_msg(value)))
                if ok is None:
                    row['no answer'] += 1
                    print(f'  {full} {name} = {str(value)[:40]}: NO ANSWER', flush=True)
                    if graph.dead():
                        print('  dead:', graph.dead(), flush=True)
                        return
                elif ok:
                    row['accepted'] += 1
                    row.setdefault('accepted values', []).append(f'{name}={str(value)[:24]}')
                    probe.set(full, Parameter(name=name, value=pv))     # back to the original
                else:
                    row['refused'] += 1
                    if not reason:
                        row['refused without reason'] += 1
        runs, how = probe.loop_runs()
        row['loop after'] = how if runs else f'BROKEN: {how}'
        row['dead'] = graph.dead()
        print(f'{full}: {row}', flush=True)
        row['accepted values'] = ', '.join(row.get('accepted values', []))


async def _ws_attacks(graph: Graph, probe_params: dict[str, dict[str, Any]]) -> dict[str, Any]:
    import aiohttp
    url = f'http://127.0.0.1:{graph.web_port}'
    out: dict[str, Any] = {}
    async with aiohttp.ClientSession() as session:
        for what, headers in (('foreign Origin', {'Origin': 'http://evil.example'}),
                              ('rebinding Host', {'Host': f'evil.example:{graph.web_port}'}),
                              ('null Origin', {'Origin': 'null'}),
                              ('Origin on another port', {'Origin': 'http://127.0.0.1:1'})):
            try:
                async with session.ws_connect(f'{url}/ws', headers=headers):
                    out[what] = 'ACCEPTED'
            except aiohttp.WSServerHandshakeError as exc:
                out[what] = f'refused {exc.status}'
            async with session.get(f'{url}/', headers=headers) as resp:
                out[what + ' (GET)'] = resp.status
        async with session.ws_connect(f'{url}/ws', max_msg_size=0) as ws:
            pending: dict[int, dict] = {}
            answers: dict[int, dict] = {}

            async def reader() -> None:
                async for msg in ws:
                    if msg.type == aiohttp.WSMsgType.TEXT:
                        event = json.loads(msg.data)
                        if event.get('type') in ('set_result', 'command_result') \
                                and event.get('id') in pending:
                            answers[event['id']] = event
            task = asyncio.ensure_future(reader())
            ids = iter(range(1, 10 ** 9))

            async def send(message: dict, timeout: float = 15.0) -> dict | None:
                i = next(ids)
                pending[i] = message
                await ws.send_str(json.dumps({**message, 'id': i}))
                end = time.monotonic() + timeout
                while i not in answers and time.monotonic() < end:
                    await asyncio.sleep(0.01)
                return answers.get(i)
            # writes without / with a wrong token
            for what, token in (('set without token', None), ('set with wrong token', 'x' * 33)):
                msg = {'type': 'set', 'node': '/controller', 'name': 'u_max', 'text': '0.5'}
                if token:
                    msg['token'] = token
                answer = await send(msg)
                out[what] = 'ACCEPTED' if answer and answer['successful'] else 'refused'
            # malformed frames: the connection and the server go on
            for frame in ('{', '[]', '"x"', 'null', json.dumps({'type': 'set', 'token': TOKEN}),
                          json.dumps({'type': 'bogus', 'token': TOKEN}),
                          json.dumps({'type': 'preview', 'node': '/controller', 'token': TOKEN,
                                      'changes': {str(i): 1 for i in range(10000)}})):
                await ws.send_str(frame)
            try:
                await ws.send_str('x' * (2 << 20))       # over the server's 1 MiB limit
            except Exception as exc:                     # noqa: BLE001
                out['2 MiB frame'] = f'send failed: {exc}'
            await asyncio.sleep(0.5)
            out['2 MiB frame'] = out.get('2 MiB frame', 'closed by server' if ws.closed
                                         else 'connection open')
            task.cancel()
        # every parameter with hostile texts, with the token
        counts = {'sets': 0, 'refused': 0, 'accepted': 0, 'no answer': 0}
        async with session.ws_connect(f'{url}/ws', max_msg_size=0) as ws:
            answers = {}
            pending = {}
            task = asyncio.ensure_future(reader())
            try:
                await _hostile_sets(probe_params, send, ws, counts)
            except Exception as exc:             # noqa: BLE001 - the server went away
                counts['stopped'] = f'{type(exc).__name__}: {exc}'
            task.cancel()
        out['hostile sets'] = counts
    return out


async def _hostile_sets(probe_params: dict[str, dict[str, Any]], send: Any, ws: Any,
                        counts: dict[str, Any]) -> None:
    """A set of every parameter of every node with the hostile texts of its type."""
    for full, params in probe_params.items():
        for name, pv in params.items():
            if name == 'use_sim_time':
                continue
            for text in TEXTS_BY_TYPE.get(pv.type, ['x']):
                counts['sets'] += 1
                answer = await send({'type': 'set', 'node': full, 'name': name,
                                     'text': text, 'token': TOKEN})
                if answer is None:
                    counts['no answer'] += 1
                    print(f'  WS {full} {name} = {text[:30]!r}: no answer', flush=True)
                    if ws.closed:
                        break
                elif answer['successful']:
                    counts['accepted'] += 1
                    await send({'type': 'set', 'node': full, 'name': name,
                                'text': _text_of(pv), 'token': TOKEN})
                else:
                    counts['refused'] += 1


def _text_of(pv: Any) -> str:
    """A ParameterValue as the page would type it."""
    from rclpy.parameter import parameter_value_to_python
    value = parameter_value_to_python(pv)
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if hasattr(value, 'tolist'):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return json.dumps(list(value))
    return str(value)


def phase_dashboard(graph: Graph, probe: Probe, figures: dict[str, Any]) -> None:
    import threading
    params = {full: probe.params_of(full) for full in ('/controller', '/plant', '/reference',
                                                        '/b/opcua_bridge')}
    box: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: box.update(out=asyncio.run(_ws_attacks(graph, params))))
    thread.start()
    while thread.is_alive():
        probe.spin(0.2)
    runs, how = probe.loop_runs()
    figures['dashboard'] = {**box.get('out', {'error': 'the attack script failed'}),
                            'loop after': how if runs else f'BROKEN: {how}',
                            'dead': graph.dead()}
    print(f"dashboard: {figures['dashboard']}", flush=True)


def phase_topics(graph: Graph, probe: Probe, figures: dict[str, Any]) -> None:
    from builtin_interfaces.msg import Time
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    pubs = {t: probe.node.create_publisher(JointState, t, 10)
            for t in ('measurement', 'setpoint', 'manipulated', 'disturbance', '/b/manipulated')}
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    probe.spin(2.0)                                   # matched
    now = time.time_ns()
    channel = {'measurement': 'y', 'setpoint': 'y', 'manipulated': 'u', 'disturbance': 'v',
               '/b/manipulated': 'u'}
    sent = 0
    rows: dict[str, str] = {}
    for topic, pub in pubs.items():
        ch = channel[topic]
        cases = [('+10 s', [ch], [1.0], 10 * 10 ** 9), ('+1e6 s', [ch], [1.0], 10 ** 15),
                 ('2038 (int32 seconds, the largest)', [ch], [1.0], (2 ** 31 - 1) * 10 ** 9 - now),
                 ('names != positions', [ch, 'x'], [1.0], 0), ('100 000 names',
                  [f'n{i}' for i in range(100_000)], [1.0] * 100_000, 0),
                 ('NaN', [ch], [math.nan], 0), ('inf', [ch], [math.inf], 0),
                 ('1e308', [ch], [1e308], 0), ('no channel', [], [], 0),
                 ('repeated name', [ch, ch], [1.0, 2.0], 0), ('stamp 0', [ch], [1.0], -now)]
        for what, names, values, ahead in cases:
            msg = JointState(name=names, position=values)
            t = time.time_ns() + ahead
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(max(t, 0), 10 ** 9)
            msg.header.stamp.sec = min(msg.header.stamp.sec, 2 ** 31 - 1)
            msg.header.frame_id = 'f' * 10000 if what == 'NaN' else ''
            pub.publish(msg)
            sent += 1
            probe.spin(0.1)
        runs, how = probe.loop_runs()
        rows[topic] = how if runs else f'BROKEN: {how}'
        print(f'  {topic}: {rows[topic]}', flush=True)
    # a second time origin, an hour ahead, latched; a flood of audit records
    origin_pub = probe.node.create_publisher(Time, 'time_origin', latched)
    t = time.time_ns() + 3600 * 10 ** 9
    origin_pub.publish(Time(sec=t // 10 ** 9, nanosec=t % 10 ** 9))
    from tank_control.nodes.params import AUDIT_QOS
    audit = probe.node.create_publisher(String, '/parameter_audit', AUDIT_QOS)
    probe.spin(1.0)
    for i in range(200):
        audit.publish(String(data=['{' * 10000, 'x' * 100_000, '{"node": 1}', '[]',
                                   json.dumps({'node': '/controller', 'name': 'u_max', 'old': 1,
                                               'new': math.nan})][i % 5]))
    sent += 201
    probe.spin(3.0)
    runs, how = probe.loop_runs(5.0)
    rows['time_origin +1 h, /parameter_audit junk'] = how if runs else f'BROKEN: {how}'
    probe.node.destroy_publisher(origin_pub)
    counters = {name: {k: v for k, v in d.items() if any(
        w in k for w in ('future', 'ignored', 'oversized', 'unknown', 'refused', 'out_of'))
        and v not in ('0', '')} for name, d in probe.diag.items()}
    figures['topics'] = {'messages': sent, **rows, 'dead': graph.dead(), 'counters': counters}
    print(f"topics: {figures['topics']}", flush=True)


async def _opcua_writes(endpoint: str) -> dict[str, str]:
    from asyncua import Client, ua
    out = {}
    async with Client(endpoint, timeout=10) as client:
        node = client.get_node('ns=2;s=Plant.u')
        for what, variant in (('NaN', ua.Variant(math.nan, ua.VariantType.Double)),
                              ('inf', ua.Variant(math.inf, ua.VariantType.Double)),
                              ('-inf', ua.Variant(-math.inf, ua.VariantType.Double)),
                              ('1e308', ua.Variant(1e308, ua.VariantType.Double)),
                              ('5e-324', ua.Variant(5e-324, ua.VariantType.Double)),
                              ('string', ua.Variant('12', ua.VariantType.String)),
                              ('bool', ua.Variant(True, ua.VariantType.Boolean)),
                              ('Int64 max', ua.Variant(2 ** 63 - 1, ua.VariantType.Int64)),
                              ('Float', ua.Variant(3.0, ua.VariantType.Float))):
            try:
                await node.write_value(ua.DataValue(Value=variant))
                out[what] = 'written'
            except Exception as exc:       # noqa: BLE001 - the server's refusal
                out[what] = f'refused ({type(exc).__name__})'
    return out


def phase_opcua(graph: Graph, probe: Probe, figures: dict[str, Any]) -> None:
    import threading
    box: dict[str, Any] = {}
    thread = threading.Thread(target=lambda: box.update(
        out=asyncio.run(_opcua_writes(graph.endpoint))))
    thread.start()
    while thread.is_alive():
        probe.spin(0.2)
    runs, how = probe.loop_runs()
    figures['opcua writes to the plant'] = {**box.get('out', {'error': 'client failed'}),
                                            'loop after': how if runs else f'BROKEN: {how}',
                                            'dead': graph.dead()}
    print(f"opcua: {figures['opcua writes to the plant']}", flush=True)


def _hostile_values() -> list[tuple[str, Any, Any, Any]]:
    """(what, value, StatusCode, SourceTimestamp offset [s] or a datetime or None)."""
    import datetime

    from asyncua import ua
    d = ua.VariantType.Double
    return [('NaN', ua.Variant(math.nan, d), ua.StatusCodes.Good, 0.0),
            ('inf', ua.Variant(math.inf, d), ua.StatusCodes.Good, 0.0),
            ('1e308', ua.Variant(1e308, d), ua.StatusCodes.Good, 0.0),
            ('a string', ua.Variant('12', ua.VariantType.String), ua.StatusCodes.Good, 0.0),
            ('a bool', ua.Variant(True, ua.VariantType.Boolean), ua.StatusCodes.Good, 0.0),
            ('UInt64 max', ua.Variant(2 ** 64 - 1, ua.VariantType.UInt64), ua.StatusCodes.Good,
             0.0),
            ('Bad status', ua.Variant(1.0, d), ua.StatusCodes.BadSensorFailure, 0.0),
            ('Uncertain status', ua.Variant(1.0, d), ua.StatusCodes.UncertainLastUsableValue,
             0.0),
            ('stamped in 2100', ua.Variant(1.0, d), ua.StatusCodes.Good,
             datetime.datetime(2100, 1, 1, tzinfo=datetime.timezone.utc)),
            ('stamped +10 s', ua.Variant(1.0, d), ua.StatusCodes.Good, 10.0),
            ('stamped in 1970', ua.Variant(1.0, d), ua.StatusCodes.Good,
             datetime.datetime(1970, 1, 2, tzinfo=datetime.timezone.utc)),
            ('stamped -10 s', ua.Variant(1.0, d), ua.StatusCodes.Good, -10.0),
            ('no SourceTimestamp', ua.Variant(1.0, d), ua.StatusCodes.Good, None)]


async def _hostile_server(port: int, ready: Any, done: Any, log: list[str]) -> None:
    """A server whose Level is first normal (stamped now, 10 Hz), then each hostile value for
    3 samples, then normal again for 3 s."""
    import datetime

    from asyncua import Server, ua
    server = Server()
    await server.init()
    server.set_endpoint(f'opc.tcp://127.0.0.1:{port}/hostile')
    idx = await server.register_namespace('urn:hostile')
    obj = await server.nodes.objects.add_object(ua.NodeId('H', idx), 'H')
    level = await obj.add_variable(ua.NodeId('H.Level', idx), 'Level',
                                   ua.Variant(0.0, ua.VariantType.Double))
    inflow = await obj.add_variable(ua.NodeId('H.Inflow', idx), 'Inflow',
                                    ua.Variant(0.0, ua.VariantType.Double))
    await inflow.set_writable()
    utc = datetime.timezone.utc

    async def put(value: Any, code: int, stamp: Any) -> None:
        now = datetime.datetime.now(utc)
        when = (now + datetime.timedelta(seconds=stamp) if isinstance(stamp, float)
                else stamp)
        await server.write_attribute_value(level.nodeid, ua.DataValue(
            Value=value, StatusCode=ua.StatusCode(code), SourceTimestamp=when,
            ServerTimestamp=now))
    async with server:
        ready.set()
        k = 0.0
        while not done.is_set() and k < 600:         # normal until the bridge publishes
            k += 1
            await put(ua.Variant(k, ua.VariantType.Double), ua.StatusCodes.Good, 0.0)
            await asyncio.sleep(0.1)
        for what, value, code, stamp in _hostile_values():
            log.append(what)
            for _ in range(3):
                await put(value, code, stamp)
                await asyncio.sleep(0.1)
        log.append('normal')
        for _ in range(30):
            k += 1
            await put(ua.Variant(k, ua.VariantType.Double), ua.StatusCodes.Good, 0.0)
            await asyncio.sleep(0.1)
        log.append('end')


def phase_server(graph: Graph, probe: Probe, figures: dict[str, Any]) -> None:
    """A hostile OPC UA server behind a second bridge (/c): every value it publishes."""
    import threading

    from sensor_msgs.msg import JointState
    port = free_port()
    ready, started = threading.Event(), threading.Event()
    log: list[str] = []
    thread = threading.Thread(target=lambda: asyncio.run(_hostile_server(port, ready, started,
                                                                         log)), daemon=True)
    thread.start()
    assert ready.wait(60), 'the hostile server does not start'
    params = graph.tmp / 'bridge_c.yaml'
    params.write_text(json.dumps({'/**': {'ros__parameters': {
        'endpoint': f'opc.tcp://127.0.0.1:{port}/hostile', 'sample_time': 0.1,
        'measurement.channels': ['y'], 'measurement.y.node_id': 'ns=2;s=H.Level',
        'manipulated.channels': ['u'], 'manipulated.u.node_id': 'ns=2;s=H.Inflow',
        'range.u': [-1.0, 1.0]}}}))
    seen: list[tuple[float, int, float, str]] = []      # (arrival wall s, stamp ns, y, phase)
    probe.node.create_subscription(JointState, '/c/measurement', lambda m: seen.append(
        (time.time(), m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec,
         m.position[0] if len(m.position) else math.nan, log[-1] if log else 'normal')), 50)
    graph._start('opcua_bridge_c', 'opcua_bridge_node', ['-r', '__ns:=/c', '--params-file',
                                                         str(params)])
    probe.wait(lambda: len(seen) >= 5, 120)
    started.set()
    probe.wait(lambda: 'end' in log, 60)
    probe.spin(1.0)
    bad_values = [(p, y) for _, _, y, p in seen if not math.isfinite(y) or abs(y) > 1e6]
    ahead = [(p, round((s / 1e9) - t, 3)) for t, s, _, p in seen if s / 1e9 - t > 1.0]
    after = [1 for _, _, _, p in seen if p in ('normal', 'end')]
    diag = probe.diag.get(f'opcua_bridge opc.tcp://127.0.0.1:{port}/hostile', {})
    figures['hostile OPC UA server'] = {
        'values served': len(_hostile_values()) * 3, 'published': len(seen),
        'published non-finite or |y| > 1e6': bad_values, 'published stamped > 1 s ahead': ahead,
        'published after the attack': len(after), 'dead': graph.dead(),
        'bridge counters': {k: v for k, v in diag.items() if k in (
            'bad_status', 'rejected_future', 'before_origin', 'receive_stamps', 'state')}}
    print(f"server: {figures['hostile OPC UA server']}", flush=True)


def lockstep_run(duration: float = 40.0, only: list[str] | None = None,
                 cases: list[int] | None = None) -> dict[str, Any]:
    """``tank-control run config/ipdt_pid.yaml`` in lockstep (real time) while the attacker
    publishes the hostile messages of ``phase_topics`` and also on ``applied_input``,
    ``recorded`` and a non-zero ``time_origin``: the run must end complete, every tick kept."""
    import rclpy
    from builtin_interfaces.msg import Time
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from tank_control.harness import domains
    out = Path(tempfile.mkdtemp(prefix='hostile_lockstep_')) / 'run'
    with domains.claimed() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1',
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node('hostile_lockstep', context=context)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        ticks = [-1]
        node.create_subscription(JointState, 'measurement', lambda m: ticks.__setitem__(
            0, max(ticks[0], m.header.stamp.sec * 10 + m.header.stamp.nanosec // 10 ** 8)), 10)
        harness = subprocess.Popen(
            [sys.executable, '-m', 'tank_control.harness.cli', 'run',
             str(REPO / 'config/ipdt_pid.yaml'), '--out', str(out), '--duration', str(duration),
             '--rtf', '1', '--quiet'], env=env, cwd=out.parent, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)   # --quiet: little output
        sent = 0
        try:
            end = time.monotonic() + 180
            while ticks[0] < 50 and time.monotonic() < end and harness.poll() is None:
                executor.spin_once(timeout_sec=0.05)
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            pubs = {t: node.create_publisher(JointState, t, 10) for t in (
                'measurement', 'setpoint', 'manipulated', 'disturbance', 'applied_input',
                'recorded')}
            origin = node.create_publisher(Time, 'time_origin', latched)
            t_end = time.monotonic() + 2
            while time.monotonic() < t_end:
                executor.spin_once(timeout_sec=0.05)
            base_ns = (ticks[0] // 10) * 10 ** 9
            for topic, pub in pubs.items():
                if only and topic not in only:
                    continue
                ch = {'measurement': 'y', 'setpoint': 'y', 'disturbance': 'v'}.get(topic, 'u')
                for i, (names, values, ahead) in enumerate((([ch], [1.0], 10 ** 10), ([ch], [1.0], 10 ** 15),
                                             ([ch], [math.nan], 0), ([ch], [1e308], 0),
                                             ([f'n{i}' for i in range(100_000)],
                                              [1.0] * 100_000, 0), ([ch, 'x'], [1.0], 0),
                                             ([ch], [1.0], -base_ns))):
                    if cases and i not in cases:
                        continue
                    msg = JointState(name=names, position=values)
                    t = max(0, base_ns + ahead)
                    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 10 ** 9)
                    pub.publish(msg)
                    sent += 1
                    executor.spin_once(timeout_sec=0.05)
            if not only or 'time_origin' in only:
                origin.publish(Time(sec=int(time.time()) + 3600))
                sent += 1
            try:
                harness.wait(duration * 2 + 60)
            except subprocess.TimeoutExpired:
                pass                         # a stalled run: killed below, reported
        finally:
            if harness.poll() is None:
                harness.kill()
                harness.wait()
            node.destroy_node()
            rclpy.shutdown(context=context)
    metrics = json.loads((out / 'metrics.json').read_text()) if (out / 'metrics.json').exists() \
        else {}
    rows = (out / 'trace.csv').read_text().count('\n') - 1 if (out / 'trace.csv').exists() else 0
    return {'messages': sent, 'rc': harness.returncode, 'complete': metrics.get('complete', False),
            'trace rows': rows, 'expected ticks': int(duration * 10) + 1,
            'out': str(out), 'tail': (harness.stdout.read() if harness.stdout else '')[-600:]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--phases', nargs='+',
                    default=['params', 'dashboard', 'topics', 'opcua', 'server'])
    ap.add_argument('--domain', type=int, default=random.randint(120, 200))
    ap.add_argument('--json', help='write the figures here')
    ap.add_argument('--keep', action='store_true', help='keep the nodes\' logs (printed path)')
    ap.add_argument('--lockstep', action='store_true', help='only the lockstep harness run')
    ap.add_argument('--only', nargs='+', help='lockstep: only these topics')
    ap.add_argument('--cases', nargs='+', type=int, help='lockstep: only these message cases '
                    '(0 +10 s, 1 +1e6 s, 2 NaN, 3 1e308, 4 100 000 names, 5 names != positions, '
                    '6 stamped 0)')
    args = ap.parse_args()
    if args.lockstep:
        result = lockstep_run(only=args.only, cases=args.cases)
        print(json.dumps(result, indent=1))
        return 0 if result['complete'] and result['rc'] == 0 else 1
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    tmp = Path(tempfile.mkdtemp(prefix='hostile_'))
    graph = Graph(tmp, args.domain)
    figures: dict[str, Any] = {}
    graph.start()
    probe = Probe()
    try:
        assert probe.wait(lambda: len(probe.y) > 10, 120), 'the loop does not start'
        graph.start_bridge()
        assert probe.wait(lambda: probe.diag.get(f'opcua_bridge {graph.endpoint}', {}).get(
            'state') == 'connected', 120), 'the bridge does not connect'
        started = time.monotonic()
        for phase in args.phases:
            {'params': phase_params, 'dashboard': phase_dashboard, 'topics': phase_topics,
             'opcua': phase_opcua, 'server': phase_server}[phase](graph, probe, figures)
        figures['wall s'] = round(time.monotonic() - started, 1)
        figures['dead at the end'] = graph.dead()
        tracebacks = {n: graph.log(n).count('Traceback') for n in graph.procs}
        figures['tracebacks in logs'] = tracebacks
    finally:
        graph.stop()
        probe.node.destroy_node()
        probe.rclpy.shutdown()
    print(json.dumps(figures, indent=1, default=str))
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=1, default=str))
    print(f'logs: {tmp}' if args.keep else '', flush=True)
    return 0 if not figures['dead at the end'] else 1


if __name__ == '__main__':
    sys.exit(main())
