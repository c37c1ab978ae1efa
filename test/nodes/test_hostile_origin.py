"""A `time_origin` published by another process far ahead of the nodes' clocks (issue 30 re-run):
the wall-mode controller and reference keep the origin they hold and the loop goes on. Real DDS,
config/ipdt_pid.yaml in wall mode; every wait is on a condition with a deadline."""
from __future__ import annotations

import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState

from tank_control.core.stamps import origin_refusal
from tank_control.nodes.messages import ORIGIN_QOS, SIGNAL_QOS, ns_to_stamp

CONFIG = 'config/ipdt_pid.yaml'
S = 10 ** 9


def test_origin_refusal_takes_a_plant_restart_and_refuses_one_far_ahead():
    now, ts, tol = 1000 * S, S // 10, S // 2
    assert origin_refusal(now + 3600 * S, None, now, tol, ts) is None     # the first: taken
    assert origin_refusal(now + 3600 * S, now + 3600 * S, now, tol, ts) is None   # the one held
    assert origin_refusal(now + S // 5 + ts, now - 60 * S, now, tol, ts) is None  # a restart
    assert origin_refusal(now - 3600 * S, now, now, tol, ts) is None      # a late latched one
    reason = origin_refusal(now + 3600 * S, now - 60 * S, now, tol, ts)
    assert reason and 'time_origin 3600 s ahead' in reason and 'refused' in reason


def test_a_time_origin_an_hour_ahead_does_not_stop_the_loop(procs, node_cmd, ros_env, probe):
    """Before: the controller and the reference took it as the plant's new session and the
    controller published nothing until real time reached it (an hour)."""
    for name in ('plant', 'controller', 'reference'):
        procs.start(name, node_cmd(f'{name}_node', '--params-file', CONFIG,
                                   '-p', 'clock_mode:=wall'), env=ros_env)
    got: dict[str, list[float]] = {'manipulated': [], 'setpoint': []}
    diag: dict[str, str] = {}
    node = probe.node
    for topic in got:
        node.create_subscription(JointState, topic, lambda m, t=topic: got[t].append(
            time.monotonic()), SIGNAL_QOS)

    def on_diag(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith('controller'):
                diag.update({kv.key: kv.value for kv in status.values})
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 50)
    assert probe.wait_for(lambda: len(got['manipulated']) > 20, 120), 'the loop runs'
    hostile = node.create_publisher(Time, 'time_origin', ORIGIN_QOS)
    assert probe.wait_for(lambda: hostile.get_subscription_count() >= 2, 60)
    hostile.publish(ns_to_stamp(time.time_ns() + 3600 * S))
    sent = time.monotonic()
    # 30 outputs (10 per second) and 5 setpoints (the reference samples every second) after
    # it; before: none after the first few
    assert probe.wait_for(lambda: sum(t > sent for t in got['manipulated']) >= 30
                          and sum(t > sent for t in got['setpoint']) >= 5, 60), \
        (sum(t > sent for t in got['manipulated']), sum(t > sent for t in got['setpoint']))
    assert probe.wait_for(lambda: int(diag.get('rejected_future', 0)) >= 1, 60), diag
