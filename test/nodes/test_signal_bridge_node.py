"""signal_bridge_node over real DDS: controller_node closes the loop in wall mode through the
bridge with a driver stood in for by the test (a "device": integrates the valve command it
receives as std_msgs/Float64, publishes the level as std_msgs/Float64 — no stamp); hostile
values from the driver and from the graph are refused, counted on /diagnostics, and never
reach the loop or the valve. Every wait is on a condition with a deadline."""
from __future__ import annotations

import json
import math
import time

import pytest

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from tank_control.nodes.messages import ORIGIN_QOS, from_joint_state, stamp_to_ns, to_joint_state

RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
TS = 0.1          # the loop's sample time [s]
GAIN = 1.0        # the device: y' = GAIN u
KP = 2.0          # PI control of the integrator: crossover ≈ KP·GAIN = 2 rad/s
TI = 2.0          # [s] the PI's zero at 0.5 rad/s. Not P alone: a measurement gap on a busy
                  # machine holds the output (fail_safe hold), and the return re-initialises
                  # the law bumplessly — without integral action that bias stays, an offset
                  # (docs/controllers.md); the integral removes it.
U_MAX = 5.0


def params(tmp_path, publish: str = 'each') -> str:
    values = {
        'signal_bridge': {'ros__parameters': {
            'sample_time': TS, 'measurement.channels': ['y'], 'measurement.y.topic': '/dev/level',
            'measurement.y.type': 'Float64', 'manipulated.channels': ['u'],
            'manipulated.u.topic': '/dev/valve', 'diagnostics_period': 0.2,
            'measurement.publish': publish}},
        'controller': {'ros__parameters': {
            'controller': 'pid', 'clock_mode': 'wall', 'sample_time': TS, 'output_names': ['y'],
            'input_names': ['u'], 'kp': KP, 'ti': TI, 'u_min': -U_MAX, 'u_max': U_MAX,
            'fail_safe': 'hold'}},
        'reference': {'ros__parameters': {
            'clock_mode': 'wall', 'sample_time': TS, 'setpoint.channels': ['y'],
            'setpoint.y.times': [0.0, 2.0], 'setpoint.y.values': [0.0, 1.0]}},
    }
    path = tmp_path / 'bridge.yaml'
    path.write_text(json.dumps(values))      # JSON is YAML, with every string quoted
    return str(path)


class Device:
    """The driver's side in the test: integrates the valve command, publishes the level."""

    def __init__(self, probe) -> None:
        node = probe.node
        self.level = 0.0
        self.commands: list[float] = []
        self.last = time.monotonic()
        self.pub = node.create_publisher(Float64, '/dev/level', 10)
        node.create_subscription(Float64, '/dev/valve', self._on_command, 10)
        node.create_timer(TS, self._tick)

    def _on_command(self, msg: Float64) -> None:
        self.commands.append(msg.data)

    def _tick(self) -> None:
        now = time.monotonic()
        u = self.commands[-1] if self.commands else 0.0
        self.level += GAIN * u * (now - self.last)
        self.last = now
        self.pub.publish(Float64(data=self.level))


@pytest.mark.parametrize('publish', ['each', 'sample'])
def test_controller_node_closes_the_loop_through_the_bridge_and_hostile_values_are_refused(
        publish, procs, node_cmd, ros_env, probe, tmp_path):
    file = params(tmp_path, publish)
    device = Device(probe)
    node = probe.node
    y, u, r, origins, diags = [], [], [], [], []
    node.create_subscription(JointState, 'setpoint',
                             lambda m: r.append(from_joint_state(m)), RECORD_QOS)
    node.create_subscription(JointState, 'measurement',
                             lambda m: y.append(from_joint_state(m)), RECORD_QOS)
    node.create_subscription(JointState, 'manipulated',
                             lambda m: u.append(from_joint_state(m)), RECORD_QOS)
    node.create_subscription(Time, 'time_origin', lambda m: origins.append(stamp_to_ns(m)),
                             ORIGIN_QOS)
    node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: diags.extend(
        {'level': s.level, 'message': s.message, **{kv.key: kv.value for kv in s.values}}
        for s in m.status if s.name == 'signal_bridge'), 50)
    controller_diags = []        # for the failure message
    node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: controller_diags.extend(
        (s.message, {kv.key: kv.value for kv in s.values})
        for s in m.status if s.name.startswith('controller')), 50)
    for name in ('signal_bridge', 'controller', 'reference'):
        procs.start(name, node_cmd(f'{name}_node', '--params-file', file), env=ros_env)

    # y follows the setpoint step 0 -> 1 at t = 2 s (PI control: no offset)
    assert probe.wait_for(lambda: abs(device.level - 1.0) < 0.02 and len(device.commands) > 30,
                          120), (device.level, device.commands[-3:], u[-3:], y[-3:], diags[-1:],
                                 len(r), r[:2], r[-2:], origins, controller_diags[-1:],
                                 [procs.processes[n].tail(10) for n in procs.processes])
    origin = origins[-1]
    assert all(stamp >= origin for stamp, _, _ in y)      # nothing before the origin
    # the measurements are the device's values, stamped on arrival (wall clock, ns)
    assert abs(y[-1][0] / 1e9 - time.time()) < 5.0 and y[-1][1] == ('y',)
    if publish == 'sample':                # on the loop's grid
        assert all((stamp - origin) % 100_000_000 == 0 for stamp, _, _ in y)
    # the valve got the controller's outputs, within its limits
    assert {v for _, _, (v,) in u[-5:]} & set(device.commands[-10:])
    assert all(-U_MAX <= c <= U_MAX for c in device.commands)

    # hostile: the driver sends NaN, inf; somebody on the graph sends manipulated NaN and a
    # value beyond the actuator's range (range.u defaults to the controller's u_min/u_max)
    seen = len(y)
    for bad in (math.nan, math.inf):
        device.pub.publish(Float64(data=bad))
    intruder = node.create_publisher(JointState, 'manipulated', 10)
    commands = len(device.commands)

    def intrude() -> None:       # again until counted: the bridge may match the intruder late
        stamp = time.time_ns()
        intruder.publish(to_joint_state(stamp, ['u'], [math.nan]))
        intruder.publish(to_joint_state(stamp + 1, ['u'], [1e6]))
    timer = node.create_timer(0.2, intrude)

    def counted() -> bool:
        last = diags[-1] if diags else {}
        return int(last.get('nonfinite', 0)) >= 3 and int(last.get('out_of_range', 0)) >= 1
    assert probe.wait_for(counted, 30), diags[-1:]
    node.destroy_timer(timer)
    last = diags[-1]
    assert last['level'] == b'\x01' or last['level'] == 1          # WARN
    assert 'non-finite values refused' in last['message']
    assert int(last['published']) > 30 and int(last['written']) > 30
    assert all(math.isfinite(v) for _, _, (v,) in y[seen:])         # never on measurement
    assert all(math.isfinite(c) and abs(c) <= U_MAX for c in device.commands[commands:])
    # and the loop goes on
    n = len(device.commands)
    assert probe.wait_for(lambda: len(device.commands) > n + 10, 30)
    # still at the setpoint: a busy machine delays the loop's hops (the device integrates on
    # wall time), so the loop may ring a little before it settles again
    assert probe.wait_for(lambda: abs(device.level - 1.0) < 0.02, 60), device.level


def test_a_bad_parameter_stops_the_node_at_start_with_one_line_naming_it(procs, node_cmd,
                                                                          ros_env):
    proc = procs.start('bridge', node_cmd('signal_bridge_node', '-p',
                                          "measurement.channels:=['y']", '-p',
                                          'measurement.y.topic:=setpoint'), env=ros_env)
    assert proc.popen.wait(timeout=60) == 2
    assert proc.tail().strip() == (
        "signal_bridge_node: measurement.y.topic: 'setpoint' is one of the loop's own topics "
        "(measurement, manipulated, setpoint, disturbance, time_origin); allowed a driver's "
        'topic')
