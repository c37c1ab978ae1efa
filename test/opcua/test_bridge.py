"""The bridge's OPC UA side (tank_control/opcua/bridge.py) against real asyncua servers on
loopback, without ROS: parameters, Bad status, limits, refused writes, one write per sample."""
from __future__ import annotations

import threading
import time

import pytest
from asyncua import ua

from support.opcua_servers import wait, LagServer, free_port
from tank_control.core.params import ConfigError
from tank_control.core.ranges import Ranges
from tank_control.opcua import config
from tank_control.opcua.bridge import Bridge, Sample
from tank_control.opcua.plant_server import PlantServer

TS = 0.1



class Run:
    """A bridge with its samples and log lines collected."""

    def __init__(self, values: dict) -> None:
        self.samples: list[Sample] = []
        self.logs: list[tuple[str, str]] = []
        self.lock = threading.Lock()
        self.bridge = Bridge(config.settings_from(values), self.samples.append,
                             lambda level, text: self.logs.append((level, text)))

    def __enter__(self) -> Run:
        self.bridge.start()
        assert self.bridge.wait_first_attempt(30)
        return self

    def __exit__(self, *exc: object) -> None:
        self.bridge.stop()


def values_for(endpoint: str, level: str = '', inflow: str = '', **more) -> dict:
    out = {'endpoint': endpoint, 'sample_time': TS}
    if level:
        out.update({'measurement.channels': ['y'], 'measurement.y.node_id': level})
    if inflow:
        out.update({'manipulated.channels': ['u'], 'manipulated.u.node_id': inflow})
    out.update(more)
    return out


@pytest.mark.parametrize('change, reason', [
    ({'endpoint': 'http://x:1'}, 'endpoint: '),
    ({'measurement.y.node_id': ''}, 'measurement.y.node_id: missing'),
    ({'measurement.y.node_id': 'Tank.Level'}, 'measurement.y.node_id: '),
    ({'username': 'op'}, 'username: set, but neither password.file nor password.env'),
    ({'username': 'op', 'password.env': 'NO_SUCH_VARIABLE_X1'}, 'password.env: '),
    ({'username': 'op', 'password.file': '/no/such/file'}, 'password.file: '),
    ({'security.policy': 'Basic256Sha256'}, 'security.certificate: needed'),
    ({'measurement.channels': ['y', 'y']}, 'measurement.channels: repeated'),
    ({'range.u': [1.0, 0.0]}, 'range.u: '),
])
def test_a_bad_parameter_is_one_line_naming_it(change, reason):
    values = values_for('opc.tcp://127.0.0.1:4840/x', 'ns=2;s=A', 'ns=2;s=B')
    values.update(change)
    with pytest.raises(ConfigError) as err:
        config.settings_from(values, environ={})
    assert str(err.value).startswith(reason) and '\n' not in str(err.value)


def test_the_password_comes_from_a_file_or_an_environment_variable_never_a_parameter(tmp_path):
    secret = tmp_path / 'pw'
    secret.write_text('s3cret\n')
    base = values_for('opc.tcp://127.0.0.1:4840/x', 'ns=2;s=A', username='op')
    assert config.settings_from({**base, 'password.file': str(secret)}).password == 's3cret'
    assert config.settings_from({**base, 'password.env': 'PW'},
                                environ={'PW': 'x'}).password == 'x'
    names = {s.name for s in config.specs(base)}
    assert 'username' in names and not any('password' == n or n.endswith('.password')
                                           for n in names)


@pytest.mark.slow     # an asyncua server (4-6 s of start-up on a busy machine)
def test_bad_status_values_are_never_published_and_are_counted():
    server = LagServer(ts=TS).start()
    try:
        with Run(values_for(server.endpoint, server.level_nodeid)) as run:
            assert wait(lambda: len(run.samples) > 5)
            server.set_status(ua.StatusCodes.UncertainLastUsableValue)
            assert wait(lambda: run.bridge.counters['bad_status'] >= 5)
            count = len(run.samples)
            assert wait(lambda: run.bridge.counters['bad_status'] >= 8)
            assert len(run.samples) == count            # nothing published meanwhile
            assert [t for _, t in run.logs if 'UncertainLastUsableValue' in t]
            server.set_status(ua.StatusCodes.Good)
            assert wait(lambda: len(run.samples) > count + 3)
            assert all(s.source_stamped for s in run.samples)
    finally:
        server.close()


@pytest.mark.slow     # an asyncua server (4-6 s of start-up on a busy machine)
def test_a_bad_subscription_status_from_the_server_makes_the_bridge_subscribe_anew():
    server = LagServer(ts=TS).start()
    try:
        with Run(values_for(server.endpoint, server.level_nodeid)) as run:
            assert wait(lambda: len(run.samples) > 3)

            async def bad_status() -> None:   # what a server says of a subscription it drops
                service = server._server.iserver.subscription_service
                for sub in list(service.subscriptions.values()):
                    await sub.monitored_item_srv.trigger_statuschange(
                        ua.StatusCode(ua.StatusCodes.BadTimeout))
            server._loop.call(bad_status())
            assert wait(lambda: run.bridge.counters['connections'] >= 2)
            assert [t for _, t in run.logs if 'subscription status BadTimeout' in t]
            count = len(run.samples)
            assert wait(lambda: len(run.samples) > count + 3)
    finally:
        server.close()


@pytest.mark.slow     # an asyncua server (4-6 s of start-up on a busy machine)
def test_a_value_without_source_timestamp_is_stamped_on_receipt_and_counted():
    server = LagServer(ts=TS, u0=1.0)      # y changes every tick: a notification each
    server.source_stamps = False
    server.start()
    try:
        with Run(values_for(server.endpoint, server.level_nodeid)) as run:
            assert wait(lambda: len(run.samples) > 5)
            assert not any(s.source_stamped for s in run.samples)
            assert run.bridge.counters['receive_stamps'] >= len(run.samples)
            now = time.time_ns()
            assert all(now - 10**10 < s.stamp_ns <= now for s in run.samples)
    finally:
        server.close()


@pytest.mark.slow     # an asyncua server (4-6 s of start-up on a busy machine)
def test_writes_are_checked_against_the_limits_and_a_refusal_is_counted_and_logged_once():
    """range.u [0, 5] at the bridge: 7 is refused there (never written); the plant server's
    EURange [0, 3]: 4 is refused by the server (BadOutOfRange), counted, logged once."""
    port = free_port()
    plant = PlantServer(f'opc.tcp://127.0.0.1:{port}/plant', ['y'], ['u'],
                        Ranges({'u': (0.0, 3.0)}))
    plant.start()
    try:
        values = values_for(plant.endpoint, plant.node_id('y'), plant.node_id('u'),
                            **{'range.u': [0.0, 5.0]})
        with Run(values) as run:
            assert run.bridge.state == 'connected', run.bridge.problem
            assert run.bridge.write({'u': 7.0}, 1) and run.bridge.counters['refused_limits'] == 1
            assert run.bridge.write({'u': float('nan')}, 2)
            assert run.bridge.write({'u': 2.0}, 3) == []
            assert wait(lambda: plant.take_inputs() == {'u': 2.0})
            for i in range(4, 8):
                run.bridge.write({'u': 4.0}, i)
                assert wait(lambda n=i - 3: run.bridge.counters['refused_writes'] >= n)
            assert plant.counters['writes'] == 1
            refusals = [t for _, t in run.logs if 'refused the write' in t]
            assert len(refusals) == 1 and 'BadOutOfRange' in refusals[0]
            assert run.bridge.state == 'connected'       # a refusal is no connection loss
    finally:
        plant.stop()


@pytest.mark.slow     # an asyncua server (4-6 s of start-up on a busy machine)
def test_at_most_one_write_per_sample_instant_and_none_while_down():
    server = LagServer(ts=TS).start()
    try:
        with Run(values_for(server.endpoint, server.level_nodeid, server.inflow_nodeid)) as run:
            for value in (1.0, 2.0, 3.0):                  # one instant, three values
                run.bridge.write({'u': value}, 10)
            assert wait(lambda: run.bridge.counters['writes'] == 1)
            run.bridge.write({'u': 4.0}, 10)                # that instant is written already
            run.bridge.write({'u': 5.0}, 11)
            assert wait(lambda: run.bridge.counters['writes'] == 2)
            _, writes = server.snapshot()
            assert [v for _, v in writes] in ([1.0, 5.0], [3.0, 5.0], [2.0, 5.0])
            server.stop_server()
            assert wait(lambda: run.bridge.state == 'down')
            for i in range(12, 40):
                run.bridge.write({'u': 9.0}, i)
            assert run.bridge.counters['dropped_writes'] == 28
            server.start()
            assert wait(lambda: run.bridge.state == 'connected', 60)
            time.sleep(3 * TS)     # (a burst would come now; none may)
            assert [v for _, v in server.snapshot()[1]][2:] == []
    finally:
        server.close()


def test_the_shipped_example_files_make_valid_settings():
    """docs/opcua/bridge.yaml (+ bridge_secure.yaml): the bridge's parameters are valid, and
    the writes' limits are the controller's u_min/u_max of the same file."""
    from support import REPO
    from tank_control.core import params_file
    sections = params_file.read(str(REPO / 'docs/opcua/bridge.yaml'))
    values = params_file.values_for(sections, '/opcua_bridge')
    limits = config.controller_limits(params_file.values_for(sections, '/controller'))
    settings = config.settings_from(values, limits)
    assert settings.limits.bounds == {'F_H': (0.0, 400.0)}
    assert settings.measurement == {'h': 'ns=2;s=Tank.Level'}
    secure = params_file.values_for(params_file.read(str(REPO / 'docs/opcua/bridge_secure.yaml')),
                                    '/opcua_bridge')
    assert {s.name for s in config.specs(values)} >= set(secure)


def test_the_opcua_package_never_imports_rclpy():
    import json
    import subprocess
    import sys
    code = ('import json, sys\nimport tank_control.opcua.bridge, tank_control.opcua.config, '
            'tank_control.opcua.plant_server\nprint(json.dumps(sorted(sys.modules)))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert not [m for m in json.loads(out.stdout) if m == 'rclpy' or m.startswith('rclpy.')]


@pytest.mark.slow     # an asyncua server (4-6 s of start-up on a busy machine)
def test_a_good_value_that_is_no_finite_number_is_never_published_and_says_so():
    """A server serving NaN with status Good: counted as bad_status, not published, the log
    names the reason (before: "status Good ... not published", which explains nothing)."""
    import math
    server = LagServer(ts=TS, u0=math.nan).start()       # y is NaN from the first step on
    try:
        with Run(values_for(server.endpoint, server.level_nodeid)) as run:
            assert wait(lambda: run.bridge.counters['bad_status'] >= 3)
            assert all(math.isfinite(v) for s in run.samples for v in s.values.values())
            reasons = [t for _, t in run.logs if 'not published' in t]
            assert reasons and all('no finite number' in t for t in reasons), reasons
    finally:
        server.close()
