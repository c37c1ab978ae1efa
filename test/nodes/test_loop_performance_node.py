"""controller_node watches its loop (issue 36 §3, live): ``~/loop_performance`` (JSON) and the
verdict in /diagnostics, from the same core monitor as metrics.json and `tank-control assess`.
The node runs in the test process on the probe's executor; the measurement is fed tick by tick
(lockstep): a loop that oscillates with a 40-s period, then one held sample on a fault."""
from __future__ import annotations

import json
import math

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from tank_control.nodes.messages import SIGNAL_QOS, stamp_to_ns, to_joint_state

H_NS = 1_000_000_000                     # 1 s samples
PERIOD = 40.0                           # [s] the oscillation fed as the measurement


def test_an_oscillating_loop_is_reported_live_with_its_verdict(probe):
    from tank_control.nodes.controller_node import ControllerNode
    node = ControllerNode(parameter_overrides=[
        Parameter('controller', value='pid'), Parameter('clock_mode', value='lockstep'),
        Parameter('sample_time', value=1.0), Parameter('kp', value=1.0),
        Parameter('ti', value=20.0), Parameter('monitor.window', value=400.0),
        Parameter('monitor.period', value=50.0), Parameter('monitor.settle_time', value=0.0)])
    probe.executor.add_node(node)
    try:
        reports, diagnostics, answers, fields = [], [], {}, {}
        probe.node.create_subscription(String, '/controller/loop_performance',
                                       lambda m: reports.append(json.loads(m.data)), 10)
        probe.node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: [(diagnostics.append(s.message),
                        fields.update({kv.key: kv.value for kv in s.values}))
                       for s in m.status if s.name.startswith('controller')], 10)
        probe.node.create_subscription(
            JointState, 'manipulated',
            lambda m: answers.__setitem__(stamp_to_ns(m.header.stamp), m.position[0]),
            SIGNAL_QOS)
        meas = probe.node.create_publisher(JointState, 'measurement', SIGNAL_QOS)
        setp = probe.node.create_publisher(JointState, 'setpoint', SIGNAL_QOS)

        def tick(k: int, y: float) -> None:
            t_ns = k * H_NS
            while t_ns not in answers:
                meas.publish(to_joint_state(t_ns, ['y'], [y]))
                setp.publish(to_joint_state(t_ns, ['y'], [0.0]))
                probe.wait_for(lambda: t_ns in answers, 0.5)

        for k in range(450):
            tick(k, math.sin(2 * math.pi * k / PERIOD))
        assert probe.wait_for(lambda: len(reports) >= 8, 20.0), reports
        last = reports[-1]
        assert last['output'] == 'y' and last['input'] == 'u'
        assert last['oscillation']['detected'] is True
        assert abs(last['oscillation']['period'] - PERIOD) < 0.05 * PERIOD, last['oscillation']
        assert 'oscillat' in last['verdict']
        assert probe.wait_for(lambda: any('loop y: ' in m and 'oscillat' in m
                                          for m in diagnostics), 20.0), diagnostics[-3:]
        # the verdict as a value too (the dashboard's faceplate shows it as a badge)
        assert 'oscillat' in fields.get('loop_performance.y', ''), fields
        # a non-finite measurement: the output is held, and that time counts as fail-safe
        tick(450, math.nan)
        for k in range(451, 500):
            tick(k, math.sin(2 * math.pi * k / PERIOD))
        assert probe.wait_for(lambda: reports[-1]['fail_safe_pct'] > 0.0, 20.0), reports[-1]
    finally:
        probe.executor.remove_node(node)
        node.destroy_node()

