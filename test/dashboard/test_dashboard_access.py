"""Who may use the dashboard (docs/dashboard.md, "Access"): dashboard_node beside a real
controller_node (config/ipdt_pid.yaml) over DDS, spoken to as a hostile web page would: a
WebSocket from another site's page (its Origin) and a request naming another host (DNS
rebinding) are refused with 403 and a one-line reason; a parameter set without this start's
token, or with a wrong one, is refused and the controller keeps its value; with the token of
the URL the node logged it is applied; a read-only dashboard (``read_only``, the default on
any host but loopback) refuses every set. The unit checks of dashboard/access.py come last."""
from __future__ import annotations

import asyncio
import json
import time
from urllib.parse import parse_qs, urlsplit

import aiohttp
import pytest
from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python
from support import CONFIG
from support.browser import dashboard_url

from tank_control.dashboard import access as access_mod
from tank_control.dashboard.access import Access, derive_read_only, origins_reason

WAIT = 60.0          # s: a loaded 2-core machine; every wait ends at its event
PARAMS = str(CONFIG / 'ipdt_pid.yaml')


def start(procs, ros_env, node_cmd, *dashboard_args: str) -> str:
    procs.start('controller', node_cmd('controller_node', '--params-file', PARAMS),
                env=ros_env)
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0',
                                             *dashboard_args), env=ros_env)
    return dashboard_url(dash)


def split(url: str) -> tuple[str, str]:
    """(base URL ``http://host:port/``, token or '')."""
    parts = urlsplit(url)
    return f'{parts.scheme}://{parts.netloc}/', parse_qs(parts.query).get('token', [''])[0]


def controller_u_max(probe) -> float:
    client = probe.node.create_client(GetParameters, '/controller/get_parameters')
    try:
        assert probe.wait_for(client.service_is_ready, WAIT)
        future = client.call_async(GetParameters.Request(names=['u_max']))
        assert probe.wait_for(future.done, WAIT)
        return parameter_value_to_python(future.result().values[0])
    finally:
        probe.node.destroy_client(client)


def http_get(url: str, headers: dict[str, str]) -> tuple[int, str]:
    async def get() -> tuple[int, str]:
        async with aiohttp.ClientSession() as session, session.get(
                url, headers=headers, timeout=aiohttp.ClientTimeout(total=WAIT)) as response:
            return response.status, await response.text()
    return asyncio.run(get())


def ws_refused(url: str, **kwargs) -> tuple[int, str]:
    """Status and body of a WebSocket handshake the server must refuse."""
    async def connect() -> tuple[int, str]:
        async with aiohttp.ClientSession() as session:
            try:
                async with session.ws_connect(url + 'ws', timeout=aiohttp.ClientWSTimeout(
                        ws_receive=WAIT), **kwargs):
                    return 101, 'accepted'
            except aiohttp.WSServerHandshakeError as exc:
                return exc.status, exc.message
    return asyncio.run(connect())


def page_sets(url: str, requests: list[dict]) -> list[dict]:
    """Open the WebSocket as the dashboard's own page does (its own Origin), wait until the
    controller's panel is loaded (u_max known), send each ``set`` and return its answer."""
    async def talk() -> list[dict]:
        async with aiohttp.ClientSession() as session, session.ws_connect(
                url + 'ws', origin=url.rstrip('/')) as ws:
            loaded = False
            deadline = time.monotonic() + WAIT
            while not loaded:
                msg = json.loads((await ws.receive(deadline - time.monotonic())).data)
                views = (list(msg['nodes'].values()) if msg['type'] == 'hello'
                         else [msg['node']] if msg['type'] == 'node' else [])
                loaded = any(v['name'] == '/controller' and v['loaded']
                             and 'u_max' in v['params'] for v in views)
            answers = []
            for i, request in enumerate(requests):
                await ws.send_str(json.dumps({'type': 'set', 'node': '/controller', 'id': i,
                                              **request}))
                while True:
                    msg = json.loads((await ws.receive(deadline - time.monotonic())).data)
                    if msg['type'] == 'set_result' and msg['id'] == i:
                        answers.append(msg)
                        break
            return answers
    return asyncio.run(talk())


def page_audit(url: str, done) -> list[dict]:
    """The audit records a page gets (the hello's, then as they come) once ``done(records)``."""
    async def talk() -> list[dict]:
        async with aiohttp.ClientSession() as session, session.ws_connect(
                url + 'ws', origin=url.rstrip('/')) as ws:
            records: list[dict] = []
            deadline = time.monotonic() + WAIT
            while not done(records):
                msg = json.loads((await ws.receive(deadline - time.monotonic())).data)
                if msg['type'] == 'hello':
                    records += msg['audit']
                elif msg['type'] == 'audit':
                    records.append(msg['record'])
            return records
    return asyncio.run(talk())


def access_diagnostics(probe, done) -> dict[str, str]:
    """The dashboard's ``dashboard: access`` status on /diagnostics once ``done(values)``."""
    from diagnostic_msgs.msg import DiagnosticArray
    seen: dict[str, str] = {}

    def on(msg) -> None:
        for status in msg.status:
            if status.name == 'dashboard: access':
                seen.clear()
                seen.update({kv.key: kv.value for kv in status.values}, message=status.message)
    sub = probe.node.create_subscription(DiagnosticArray, '/diagnostics', on, 10)
    try:
        assert probe.wait_for(lambda: done(seen), WAIT), seen
        return dict(seen)
    finally:
        probe.node.destroy_subscription(sub)


def test_a_foreign_origin_and_a_rebinding_host_are_refused(procs, ros_env, node_cmd):
    url, _ = split(start(procs, ros_env, node_cmd))
    port = urlsplit(url).port
    # another site's page opening the WebSocket (the browser sends its Origin)
    status, reason = ws_refused(url, origin='http://evil.example')
    assert status == 403, reason
    status, body = http_get(url, {'Origin': 'http://evil.example'})
    assert status == 403 and body.strip().count('\n') == 0
    assert "Origin 'http://evil.example' is not allowed (parameter allowed_origins)" in body
    # DNS rebinding: evil.example resolving to 127.0.0.1, its page same-origin with itself
    rebound = {'Host': f'evil.example:{port}', 'Origin': f'http://evil.example:{port}'}
    status, body = http_get(url, {'Host': f'evil.example:{port}'})
    assert status == 403 and "Host 'evil.example:" in body and body.count('\n') == 1
    assert ws_refused(url, headers=rebound)[0] == 403
    # the dashboard's own page, by address or as localhost
    assert http_get(url, {})[0] == 200
    assert http_get(url, {'Host': f'localhost:{port}',
                          'Origin': f'http://localhost:{port}'})[0] == 200


def test_a_set_needs_the_token_of_the_logged_url(procs, ros_env, node_cmd, probe):
    url, token = split(start(procs, ros_env, node_cmd))
    assert token, 'the logged URL carries the token'
    before = controller_u_max(probe)
    refused = page_sets(url, [{'name': 'u_max', 'text': '0.5'},
                              {'name': 'u_max', 'text': '0.5',     # another first character
                               'token': ('y' if token[0] == 'x' else 'x') + token[1:]},
                              {'name': 'u_max', 'text': '0.5', 'token': token[:-1]}])
    assert [a['successful'] for a in refused] == [False] * 3
    assert refused[0]['reason'].startswith('refused: no token')
    assert refused[1]['reason'].startswith('refused: wrong token')
    assert refused[2]['reason'].startswith('refused: wrong token')
    assert controller_u_max(probe) == before != 0.5
    applied = page_sets(url, [{'name': 'u_max', 'text': '0.5', 'token': token}])
    assert applied[0]['successful'], applied
    assert controller_u_max(probe) == 0.5
    # the refusals are counted on /diagnostics
    diag = access_diagnostics(probe, lambda v: v.get('refused_token') == '3')
    assert 'wrong token' in diag['message']
    # the change is on the page's audit trail: the node's record and the dashboard's (who asked)
    records = page_audit(url, lambda rs: len([r for r in rs if r['name'] == 'u_max']) >= 2)
    sources = sorted(r['source'] for r in records if r['name'] == 'u_max')
    assert sources == ['dashboard /dashboard (page at 127.0.0.1)', 'set_parameters service']
    assert all((r['node'], r['old'], r['new']) == ('/controller', before, 0.5)
               for r in records if r['name'] == 'u_max')


@pytest.mark.parametrize('args', [('-p', 'read_only:=true'), ('-p', 'host:=0.0.0.0')],
                         ids=['read_only', 'any-interface'])
def test_a_read_only_dashboard_refuses_every_set(args, procs, ros_env, node_cmd, probe):
    url, token = split(start(procs, ros_env, node_cmd, *args))
    assert token == '', 'a read-only dashboard logs no token'
    if '0.0.0.0' in args[1]:
        url = url.replace('0.0.0.0', '127.0.0.1')
    before = controller_u_max(probe)
    refused = page_sets(url, [{'name': 'u_max', 'text': '0.5', 'token': 'anything'}])
    assert not refused[0]['successful']
    assert refused[0]['reason'].startswith('refused: this dashboard is read-only')
    assert controller_u_max(probe) == before
    assert http_get(url, {})[0] == 200            # the trends are still served


def test_a_bad_origin_or_token_setting_stops_the_node_with_one_line(ros_env, node_cmd):
    import subprocess
    bad = subprocess.run(node_cmd('dashboard_node', '-p', 'port:=0', '-p',
                                  'allowed_origins:=[self, "*"]'), env=ros_env,
                         capture_output=True, text=True, timeout=120, check=False)
    assert bad.returncode == 2 and 'Traceback' not in bad.stderr
    assert bad.stderr.strip().splitlines()[-1].startswith(
        "dashboard_node: allowed_origins: '*' is not an origin; allowed 'self' or "), bad.stderr
    short = subprocess.run(node_cmd('dashboard_node', '-p', 'port:=0'),
                           env={**ros_env, access_mod.TOKEN_ENV: 'abc'},
                           capture_output=True, text=True, timeout=120, check=False)
    assert short.returncode == 2 and 'Traceback' not in short.stderr
    assert short.stderr.strip().splitlines()[-1].startswith(
        f'dashboard_node: {access_mod.TOKEN_ENV}: allowed 16 or more characters'), short.stderr


# ---------------------------------------------------------------- dashboard/access.py

def test_access_checks_host_origin_and_token():
    lines: list[str] = []
    access = Access(['self', 'https://scada.plant.lan'], False, lines.append, token='t0k')
    assert access.http_reason('127.0.0.1:8080', None) is None
    assert access.http_reason('127.0.0.1:8080', 'http://127.0.0.1:8080') is None
    assert access.http_reason('[::1]:8080', 'http://[::1]:8080') is None
    assert access.http_reason('localhost:8080', 'http://localhost:8080') is None
    assert access.http_reason('192.168.1.5:8080', 'http://192.168.1.5:8080') is None
    assert access.http_reason('127.0.0.1:8080', 'https://scada.plant.lan:443') is None
    assert access.http_reason('scada.plant.lan', None) is None
    assert access.http_reason('127.0.0.1:8080', 'http://127.0.0.1:9999')   # another port
    assert access.http_reason('127.0.0.1:8080', 'null')
    assert access.http_reason('evil.example:8080', None)
    assert access.http_reason('', None) and access.http_reason(None, None)
    assert access.write_reason({'type': 'set'}).startswith('refused: no token')
    assert access.write_reason({'type': 'command', 'token': 't0K'}).startswith(
        'refused: wrong token')
    assert access.write_reason({'type': 'set', 'token': 'töken'})      # not ASCII: refused
    assert access.write_reason({'type': 'set', 'token': 't0k'}) is None
    assert access.write_reason({'type': 'other'}) is None
    assert access.counts() == {'host': 3, 'origin': 2, 'token': 3}
    assert len(Access([], False, print).token) >= 32            # a fresh secret per start


def test_refusals_are_logged_rate_limited_with_the_count(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(access_mod.time, 'monotonic', lambda: now[0])
    lines: list[str] = []
    access = Access(['self'], True, lines.append)
    for _ in range(5):
        assert access.write_reason({'type': 'set', 'token': access.token})
    assert len(lines) == 1 and 'read-only' in lines[0]
    now[0] += access_mod.LOG_PERIOD
    access.write_reason({'type': 'set'})
    assert len(lines) == 2 and '(4 more read_only refusals since the last line)' in lines[1]
    assert access.counts() == {'read_only': 6}


def test_read_only_follows_the_host_and_origins_are_checked():
    assert derive_read_only({'host': '127.0.0.1'}, frozenset()) == {}
    assert derive_read_only({'host': 'localhost'}, frozenset()) == {}
    assert derive_read_only({'host': '::1'}, frozenset()) == {}
    assert derive_read_only({'host': '0.0.0.0'}, frozenset()) == {'read_only': True}
    assert derive_read_only({'host': '0.0.0.0'}, frozenset({'read_only'})) == {}
    assert origins_reason(['self', 'http://a.b:1', 'https://[::1]']) is None
    assert origins_reason(['self', '*']).startswith("allowed_origins: '*' is not an origin")


def test_a_sample_stamped_in_the_future_is_not_shown_and_is_reported(procs, ros_env, node_cmd,
                                                                     probe):
    """issue 30 §1 for the dashboard (wall): a measurement stamped an hour ahead of its clock is
    not drawn (it would stretch every trend's time axis), and /diagnostics says so (WARN,
    ``rejected_future``), as the plant and controller do."""
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState

    from tank_control.nodes.messages import ORIGIN_QOS, SIGNAL_QOS, ns_to_stamp, to_joint_state
    dashboard_url(procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'),
                              env=ros_env))
    reports = []
    probe.node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: reports.extend({kv.key: kv.value for kv in s.values} | {'_message': s.message,
                                                                          '_level': s.level}
                                 for s in m.status if s.name.startswith('dashboard')), 10)
    origin = probe.node.create_publisher(Time, 'time_origin', ORIGIN_QOS)
    meas = probe.node.create_publisher(JointState, 'measurement', SIGNAL_QOS)
    now = time.time_ns()
    origin.publish(ns_to_stamp(now))
    ahead = now + 3600 * 1_000_000_000

    def refused() -> bool:
        meas.publish(to_joint_state(ahead, ['y'], [1.0]))       # until the dashboard has it
        return any(int(r.get('rejected_future', 0)) >= 1 for r in reports)
    assert probe.wait_for(refused, 30.0), reports[-3:]
    report = next(r for r in reports if int(r.get('rejected_future', 0)) >= 1)
    assert 'stamped in the future not shown' in report['_message']
    assert report['_level'] in (b'\x01', 1)


def test_a_set_of_a_value_no_parameter_message_carries_is_refused_and_the_node_lives(
        procs, ros_env, node_cmd, probe):
    """Hostile texts from a page holding the token (an integer beyond 64 bits, a number too
    large for a double in a list): each refused with the controller's reason, the dashboard
    keeps serving (before: it died at the first, OverflowError in its executor)."""
    procs.start('controller', node_cmd('controller_node', '--params-file', PARAMS),
                env=ros_env)
    dash = procs.start('dashboard', node_cmd('dashboard_node', '-p', 'port:=0'), env=ros_env)
    url, token = split(dashboard_url(dash))
    answers = page_sets(url, [
        {'name': 'stale_samples', 'text': '-9223372036854775809', 'token': token},
        {'name': 'range.y', 'text': '[1' + '0' * 400 + ', 2]', 'token': token},
        {'name': 'u_max', 'text': '0.5', 'token': token}])
    assert [a['successful'] for a in answers] == [False, False, True], answers
    assert all(a['reason'] for a in answers[:2])
    assert dash.popen.poll() is None
    assert controller_u_max(probe) == 0.5
