"""opcua_bridge_node against hostile stamps and names (issue 30 re-run), over real DDS and a real
asyncua server on loopback (support/opcua_servers). The probe plays a hostile `manipulated`
publisher; every wait is on a condition with a deadline."""
from __future__ import annotations

import json
import re
import time

from diagnostic_msgs.msg import DiagnosticArray

from support.opcua_servers import LagServer
from tank_control.nodes.messages import SIGNAL_QOS, to_joint_state

TS = 0.1
HOUR_NS = 3600 * 10**9


def bridge_params(tmp_path, server: LagServer) -> str:
    path = tmp_path / 'bridge.yaml'
    path.write_text(json.dumps({'opcua_bridge': {'ros__parameters': {
        'endpoint': server.endpoint, 'sample_time': TS, 'measurement.channels': ['y'],
        'measurement.y.node_id': server.level_nodeid, 'manipulated.channels': ['u'],
        'manipulated.u.node_id': server.inflow_nodeid, 'range.u': [-10.0, 10.0],
        'diagnostics_period': 0.2}}}))
    return str(path)


class Hostile:
    """The probe as a `manipulated` publisher, with the bridge's /diagnostics counters."""

    def __init__(self, probe) -> None:
        from sensor_msgs.msg import JointState
        self.probe = probe
        self.pub = probe.node.create_publisher(JointState, 'manipulated', SIGNAL_QOS)
        self.diag: dict[str, str] = {}
        probe.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == 'opcua_bridge':
                self.diag = {kv.key: kv.value for kv in status.values}

    def send(self, value: float, ahead_ns: int = 0, names: list[str] | None = None) -> None:
        names = names or ['u']
        self.pub.publish(to_joint_state(time.time_ns() + ahead_ns, names, [value] * len(names)))

    def connected(self) -> bool:
        return self.diag.get('state') == 'connected' and self.pub.get_subscription_count() > 0


def written(server: LagServer) -> list[float]:
    return [v for _, v in server.snapshot()[1]]


def send_until_written(hostile: Hostile, server: LagServer, value: float) -> None:
    """Publish ``value`` as a controller does, once per sample with the stamp of now, until the
    server holds it: the bridge writes at most once per sample instant, so a single message
    stamped in the instant of a value written just before is (rightly) not written."""
    deadline = time.monotonic() + 30
    while value not in written(server) and time.monotonic() < deadline:
        hostile.send(value)
        hostile.probe.wait_for(lambda: value in written(server), 2 * TS)
    assert value in written(server), written(server)


def test_a_manipulated_stamped_ahead_is_refused_and_the_writes_go_on(procs, node_cmd, ros_env,
                                                                    probe, tmp_path):
    """One `manipulated` stamped an hour (then 10 s) ahead: not written, counted as
    rejected_future on /diagnostics; the next valid values are written (before: every later
    message was "older than the last one" and the server's input stayed frozen)."""
    server = LagServer(ts=TS).start()
    try:
        procs.start('bridge', node_cmd('opcua_bridge_node', '--params-file',
                                       bridge_params(tmp_path, server)), env=ros_env)
        hostile = Hostile(probe)
        assert probe.wait_for(hostile.connected, 120), 'the bridge connects'
        for good, ahead in ((1.0, HOUR_NS), (3.0, 10 * 10**9)):
            send_until_written(hostile, server, good)
            hostile.send(good + 1.0, ahead)                     # the hostile one
            send_until_written(hostile, server, good + 0.5)
        assert 2.0 not in written(server) and 4.0 not in written(server)
        assert probe.wait_for(lambda: int(hostile.diag.get('rejected_future', 0)) >= 2, 30)
    finally:
        server.close()


def test_a_flood_of_unknown_names_is_one_log_line_per_period(procs, node_cmd, ros_env, probe,
                                                             tmp_path):
    """Ten `manipulated` of 200 unknown names each (under MAX_NAMES): a line per diagnostics
    period, not one per name (before: 2000 WARN lines)."""
    server = LagServer(ts=TS).start()
    try:
        proc = procs.start('bridge', node_cmd('opcua_bridge_node', '--params-file',
                                              bridge_params(tmp_path, server)), env=ros_env)
        hostile = Hostile(probe)
        assert probe.wait_for(hostile.connected, 120), 'the bridge connects'
        started = time.monotonic()
        for i in range(10):
            hostile.send(1.0, names=[f'x{i}_{j}' for j in range(200)])
            assert probe.wait_for(
                lambda n=200 * (i + 1): int(hostile.diag.get('refused_limits', 0)) >= n, 30)
        send_until_written(hostile, server, 2.5)
        periods = (time.monotonic() - started) / 0.2 + 2
        lines = proc.log_path.read_text().count('unknown manipulated channel')
        assert 1 <= lines <= periods, (lines, periods)
    finally:
        server.close()


class StrayFirstSample(LagServer):
    """Serves ONE level stamped an hour ahead, then nothing until ``hold`` is cleared, then its
    samples on its clock: the bridge's first sample is the stray one."""

    hold = True
    _sent = False

    async def _publish(self, stamp: int) -> None:
        if self.hold:
            if self._sent:
                return
            self._sent = True
            stamp += HOUR_NS
        await super()._publish(stamp)


def test_a_first_sample_stamped_ahead_does_not_set_the_time_origin(procs, node_cmd, ros_env,
                                                                 tmp_path):
    """The server's first value is stamped an hour ahead: refused; the time origin is announced
    on the next sample, on this host's clock (before: an hour ahead — no measurement published
    for an hour)."""
    server = StrayFirstSample(ts=TS).start()
    try:
        proc = procs.start('bridge', node_cmd('opcua_bridge_node', '--params-file',
                                              bridge_params(tmp_path, server)), env=ros_env)
        deadline = time.monotonic() + 120
        while ': connected' not in proc.log_path.read_text():
            assert time.monotonic() < deadline and proc.popen.poll() is None, \
                proc.log_path.read_text()
            time.sleep(0.05)
        server.hold = False
        while not (found := re.search(r'time origin (\d+) ns', proc.log_path.read_text())):
            assert time.monotonic() < deadline, proc.log_path.read_text()
            time.sleep(0.05)
        origin = int(found.group(1))
        assert origin < time.time_ns() + 10 * 10**9, (origin - time.time_ns()) / 1e9
        assert 'ahead of this node' in proc.log_path.read_text()
    finally:
        server.close()
