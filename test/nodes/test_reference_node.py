"""reference_node over real DDS: schedule published, runtime changes, lockstep answers."""
from __future__ import annotations

import json
import time

from builtin_interfaces.msg import Time
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState


from support.held import REFERENCE
from tank_control.nodes.messages import (CLOCK_QOS, ORIGIN_QOS, clock_msg, from_joint_state,
                                         ns_to_stamp)

RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)

def params_file(tmp_path, **extra):
    path = tmp_path / 'reference.yaml'
    # JSON is YAML with every string quoted (ROS 2 reads an unquoted y as a boolean).
    path.write_text(json.dumps({'reference': {'ros__parameters': {**REFERENCE, **extra}}}))
    return str(path)


def collect(probe, topic, arrivals=None):
    """Messages of ``topic`` as (stamp, names, values); their arrival (system time, ns) in
    ``arrivals`` when given. Keeps every message: a wall timer does not wait for the probe."""
    got = []

    def record(msg):
        if arrivals is not None:
            arrivals.append(time.time_ns())
        got.append(from_joint_state(msg))
    probe.node.create_subscription(JointState, topic, record, RECORD_QOS)
    return got


def set_param(probe, name, value):
    client = probe.node.create_client(SetParameters, '/reference/set_parameters')
    assert probe.wait_for(client.service_is_ready, 20)
    future = client.call_async(SetParameters.Request(
        parameters=[Parameter(name, value=value).to_parameter_msg()]))
    assert probe.wait_for(future.done, 10)
    return future.result().results[0]


def test_wall_mode_publishes_the_schedule_on_the_plant_time_base_and_applies_changes(
        procs, ros_env, node_cmd, probe, tmp_path):
    arrivals: list[int] = []
    setpoints = collect(probe, 'setpoint', arrivals)
    proc = procs.start('reference', node_cmd('reference_node', '--params-file',
                                             params_file(tmp_path, sample_time=0.05)), env=ros_env)
    # The probe plays the plant: its tick 0 (the time origin) 0.2 s from now, latched.
    origin = time.time_ns() + 200_000_000
    probe.node.create_publisher(Time, 'time_origin', ORIGIN_QOS).publish(ns_to_stamp(origin))
    assert probe.wait_for(lambda: any(v == (2.0,) for _, _, v in setpoints), 20), proc.tail()
    assert all(names == ('y',) for _, names, _ in setpoints)
    # Stamped at the instants origin + j·sample_time of plant time, none before tick 0, and
    # the schedule runs on plant time: 1.0 before t = 0.3 s, 2.0 from it.
    stamps = [s for s, _, _ in setpoints]
    assert all(s >= origin and (s - origin) % 50_000_000 == 0 for s in stamps)
    assert all(v == ((1.0,) if s - origin < 300_000_000 else (2.0,)) for s, _, v in setpoints)
    # Out of range: rejected with the reason, nothing changes.
    result = set_param(probe, 'setpoint.y.value', 11.0)
    assert not result.successful
    assert result.reason == 'setpoint.y.value: 11 is out of range; allowed [0, 10]'
    result = set_param(probe, 'setpoint.y.value', 7.5)
    assert result.successful, result.reason
    accepted_by = time.time_ns()       # the node had accepted the change before this instant
    # The change is in force from the next published instant: every message published after
    # the acceptance carries it — each is published wall.lead (7 ms, default) before its
    # stamp, so every one stamped more than that after the acceptance (one stamped less than
    # that after it may have gone out before it) — and the value switches once, 2.0 to 7.5.
    assert probe.wait_for(lambda: setpoints[-1][0] - 7_000_000 > accepted_by, 20)
    assert all(v == (7.5,) for s, _, v in setpoints if s - 7_000_000 > accepted_by)
    values = [v[0] for _, _, v in setpoints]
    switch = values.index(7.5)
    assert set(values[:switch]) <= {1.0, 2.0} and set(values[switch:]) == {7.5}
    # Limits are checked against the running schedule (with the override) before acceptance.
    result = set_param(probe, 'setpoint.y.min', 8.0)
    assert not result.successful
    assert result.reason == 'setpoint.y.values: 7.5 is out of range; allowed [8, 10]'
    assert set_param(probe, 'setpoint.y.min', 5.0).successful
    # Published wall.lead (7 ms, default) before their instant, never earlier: increasing,
    # each arriving here at most 7 ms before its stamp.
    stamps = [s for s, _, _ in setpoints]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert all(s - 7_000_000 <= t for s, t in zip(stamps, arrivals))


def test_wall_mode_a_shorter_sample_time_acts_at_once(procs, ros_env, node_cmd, probe,
                                                       tmp_path):
    """sample_time 30 s → 0.2 s: the next message comes on the new grid, not after the
    rest of the old 30 s period (instant 30 s of plant time)."""
    setpoints = collect(probe, 'setpoint')
    proc = procs.start('reference', node_cmd('reference_node', '--params-file',
                                             params_file(tmp_path, sample_time=30.0)), env=ros_env)
    origin = time.time_ns()
    probe.node.create_publisher(Time, 'time_origin', ORIGIN_QOS).publish(ns_to_stamp(origin))
    assert probe.wait_for(lambda: len(setpoints) >= 1, 20), proc.tail()
    assert setpoints[0][0] == origin                      # instant 0
    assert set_param(probe, 'sample_time', 0.2).successful
    assert probe.wait_for(lambda: len(setpoints) >= 3, 20), proc.tail()
    stamps = [s - origin for s, _, _ in setpoints]
    assert all(s % 200_000_000 == 0 for s in stamps)      # on the new grid ...
    assert stamps[1] < 30_000_000_000                     # ... without waiting out the old period
    assert all(b - a == 200_000_000 for a, b in zip(stamps[1:], stamps[2:]))


def test_use_sim_time_beside_a_wall_clock_plant_is_reported(procs, ros_env, node_cmd, probe,
                                                            tmp_path):
    """With use_sim_time the reference answers /clock ticks; a wall-clock plant sends none
    (it latches a non-zero time origin): ERROR on /diagnostics with the remedy, not silence."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    reports = []
    probe.node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: reports.extend(s for s in m.status if s.name == 'reference'), 10)
    proc = procs.start('reference', node_cmd('reference_node', '--params-file',
                                             params_file(tmp_path), '-p', 'use_sim_time:=true'),
                       env=ros_env)
    probe.node.create_publisher(Time, 'time_origin', ORIGIN_QOS).publish(
        ns_to_stamp(time.time_ns()))
    assert probe.wait_for(lambda: reports, 20), proc.tail()
    assert reports[0].level == DiagnosticStatus.ERROR
    assert 'the plant runs on the wall clock' in reports[0].message
    assert 'use_sim_time false' in reports[0].message


T = 100_000_000        # the plant tick of these tests [ns]


def run_clock(probe, clock, streams, last_tick):
    """Publish /clock 1 .. last_tick (tick 0 is out) and wait, after each, until every stream
    is known through the next tick (a message stamped at or after it)."""
    for k in range(1, last_tick + 1):
        clock.publish(clock_msg(k * T))
        assert probe.wait_for(lambda: all(s and s[-1][0] >= (k + 1) * T for s in streams), 20)


def test_lockstep_publishes_the_schedules_ahead_once_per_change_and_again_on_resend(
        procs, ros_env, node_cmd, probe, tmp_path):
    """lockstep (``lockstep.lookahead`` 6): on /clock t_k the schedules are published through
    t_k+6 under zero-order hold — a message at each change (the setpoint step once, the
    disturbance ramp at every tick it moves) and one at the horizon t_k+6 only when the last
    one is older than t_k+1. Read back by zero-order hold they equal the schedules at every
    tick; a re-sent tick gets again every message from the one in force at it on."""
    from support.held import per_tick
    procs.start('reference', node_cmd('reference_node', '--params-file',
                                      params_file(tmp_path, clock_mode='lockstep')), env=ros_env)
    setpoints, disturbances = collect(probe, 'setpoint'), collect(probe, 'disturbance')
    clock = probe.node.create_publisher(Clock, '/clock', CLOCK_QOS)
    # Until discovery matches, re-send tick 0 (as the plant does): the tick period is not
    # known yet, so tick 0 alone is answered.
    assert probe.wait_for(lambda: (setpoints and disturbances)
                          or clock.publish(clock_msg(0)), 20)
    run_clock(probe, clock, (setpoints, disturbances), 20)
    ticks = [k * T for k in range(22)]
    r = {k: v[0] for k, (_, v) in per_tick({s: (n, v) for s, n, v in setpoints}, ticks).items()}
    d = {k: v[0] for k, (_, v) in per_tick({s: (n, v) for s, n, v in disturbances},
                                            ticks).items()}
    assert [r[t] for t in ticks] == [1.0] * 3 + [2.0] * 19
    # Ramp from 0 at t = 0.5 s toward -0.5 at 1 /s: -0.1 at 0.6 s, -0.5 from 1.0 s.
    assert max(abs(d[k * T] - max(-0.5, min(0.0, -(k - 5) / 10))) for k in range(22)) < 1e-12
    # One message per change, holds every 6 ticks: the step at tick 3 (published on /clock
    # 1), holds at 9 (on /clock 3) and 15 (on /clock 9), 21 (on /clock 15); the ramp at
    # ticks 6-10, holds at 16 and 22.
    assert sorted({s // T for s, _, _ in setpoints}) == [0, 3, 9, 15, 21]
    assert sorted({s // T for s, _, _ in disturbances}) == [0, 6, 7, 8, 9, 10, 16, 22]
    # none twice (tick 0 was re-sent until the probe matched)
    assert sum(s > 0 for s, _, _ in setpoints) == 4 and sum(s > 0 for s, _, _ in disturbances) == 7
    # A re-sent tick gets again the messages from the one in force at it on.
    before = list(setpoints)
    clock.publish(clock_msg(20 * T))
    assert probe.wait_for(lambda: len(setpoints) >= len(before) + 2, 20)
    assert setpoints[len(before):] == [m for m in before if m[0] >= 15 * T]
