"""Lockstep: plant + PID controller + reference in three processes == core/loop.py to 1e-9.

The test records through the harness's recorder with its gate (``Recorder.enable_gate``):
the plant's disturbance input comes through the recorder, which relays a tick only once it
holds all of it, so the plant — running as fast as possible — cannot get ahead of the
recording, and every tick is compared.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message
from rclpy.utilities import get_default_context
from support import CONFIG
from support.held import HELD_TOPICS, per_tick

from tank_control.core import params_file
from tank_control.core.scenario import run_in_process
from tank_control.harness.recorder import Recorder
from tank_control.harness.trace import GATED_DISTURBANCE
from tank_control.nodes.messages import stamp_to_ns

TOPICS = {'measurement': 'y', 'setpoint': 'r', 'manipulated': 'u', 'disturbance': 'd'}


def scenario(tmp_path: Path) -> tuple[dict, Path]:
    """config/ipdt_pid.yaml, shortened, with measurement noise (same seeded draws in both)."""
    params = params_file.read(CONFIG / 'ipdt_pid.yaml')
    params['plant'].update({'noise_std': [0.01], 'seed': 7, 'lockstep.paused': True,
                            'real_time_factor': 0.0})
    params['reference'].update({'setpoint.y.times': [0.0, 1.0], 'setpoint.y.values': [0.0, 1.0],
                                'setpoint.y.ramp_rate': 0.5,
                                'disturbance.v.times': [0.0, 7.0],
                                'disturbance.v.values': [0.0, -0.1]})
    params['controller']['sample_time'] = 0.2     # every second plant tick: holds in between
    path = params_file.write(params, tmp_path / 'scenario.yaml')
    return params, path


def test_lockstep_ros_run_equals_the_in_process_loop(procs, ros_env, node_cmd, rclpy_session,
                                                     tmp_path):
    params, path = scenario(tmp_path)
    ts_ns, last_tick = 100_000_000, 120          # 12 s of simulated time
    recorder = Recorder(get_default_context(), name='test_lockstep_recorder')
    try:
        recorder.enable_gate()
        for name in ('plant', 'controller', 'reference'):
            argv = node_cmd(f'{name}_node', '--params-file', str(path))
            if name == 'plant':
                argv += ['-r', f'disturbance:={GATED_DISTURBANCE}']   # through the recorder
            procs.start(name, argv, env=ros_env)

        def logs() -> str:
            return '\n'.join(p.tail() for p in procs.processes.values())
        # Every publisher matched by the recorder, and the plant by the gate, before tick 0
        # (the plant is paused).
        assert recorder.spin_until(lambda: all(recorder.publisher_count(t) for t in TOPICS)
                                   and recorder.subscriber_count(GATED_DISTURBANCE), 60), logs()
        assert recorder.set_parameters('plant', {'lockstep.paused': False}, 30) is None, logs()
        assert recorder.spin_until(
            lambda: all(recorder.latest.get(t, -1) >= last_tick * ts_ns for t in TOPICS), 120), \
            (recorder.counts, logs())
        signals = recorder.signal_messages()
    finally:
        recorder.destroy()

    seen: dict[str, dict[int, tuple]] = {topic: {} for topic in TOPICS}
    duplicates_differ = []
    for m in signals:
        entry = (m.names, m.values)
        if seen[m.topic].setdefault(m.stamp_ns, entry) != entry:
            duplicates_differ.append((m.topic, m.stamp_ns))
    assert not duplicates_differ   # re-sent ticks were answered identically

    # Every tick of every signal was recorded and equals the in-process loop (the
    # reference's topics: by zero-order hold, one message per change).
    expected = run_in_process(params, duration=last_tick * ts_ns / 1e9)
    ticks = range(last_tick + 1)
    for topic in HELD_TOPICS:
        seen[topic] = per_tick(seen[topic], [k * ts_ns for k in ticks])
    worst: dict[str, float] = {}
    for topic, prefix in TOPICS.items():
        missing = [k for k in ticks if k * ts_ns not in seen[topic]]
        assert not missing, (topic, missing)
        names = seen[topic][0][0]
        assert all(seen[topic][k * ts_ns][0] == names for k in ticks), topic
        for i, name in enumerate(names):
            column = f'{prefix}.{name}'
            ros = np.array([seen[topic][k * ts_ns][1][i] for k in ticks])
            worst[column] = float(np.max(np.abs(ros - expected[column][:last_tick + 1])))
    assert set(worst) == set(expected.names) - {'t'}
    assert max(worst.values()) <= 1e-9, worst
    # The run is not trivial: setpoint ramp, controller action, noise, disturbance all present.
    assert expected['r.y'][-1] == 1.0 and expected['d.v'][-1] == -0.1
    assert np.ptp(expected['u.u']) > 0.1 and np.std(np.diff(expected['y.y'][:10])) > 1e-3


def test_a_slow_recorder_beside_busy_loops_holds_every_tick_without_being_a_hop(
        procs, ros_env, node_cmd, rclpy_session, tmp_path):
    """The recorder off the tick's serial path (``lockstep.record_window``): the plant runs
    ahead of it by at most 8 ticks and waits for its acknowledgments on ``recorded`` only
    when it is that far behind. With the recorder slowed down on purpose (each message costs
    it 1 ms more) and two busy loops on the machine, every message of every tick still
    reaches it — its keep-all reader alone would fill up and the plant's keep-last 10
    writers would drop — and the trace equals the in-process loop. Without the window the
    plant runs ahead, and the recorder's queue grows without bound: when the plant publishes
    its diagnostics, its tick is hundreds ahead of the last measurement the recorder has
    taken. (Measured in ticks, not seconds: beside the busy loops a starved recorder process
    may take a message seconds after it was sent, window or not.)"""
    import bisect
    import time
    params, path = scenario(tmp_path)
    ts_ns, last_tick = 100_000_000, 1000
    for i in range(2):
        procs.start(f'busy{i}', ['python3', '-c', 'while 1: pass'])
    kept = []
    taken: list[tuple[int, int]] = []      # (system time the recorder took it, tick)
    reports: list[tuple[int, int]] = []    # (system time the plant published it, its tick)

    def slow_sink(raw) -> None:
        kept.append(raw)
        if raw.topic == '/measurement':
            taken.append((raw.log_time_ns, raw.publish_time_ns // ts_ns))
        elif raw.topic == '/diagnostics':
            msg = deserialize_message(raw.data, DiagnosticArray)
            if msg.status and msg.status[0].name == 'plant':
                values = {kv.key: kv.value for kv in msg.status[0].values}
                reports.append((stamp_to_ns(msg.header.stamp),
                                round(float(values['sim_time']) * 1e9 / ts_ns)))
        end = time.perf_counter() + 0.001
        while time.perf_counter() < end:
            pass
    recorder = Recorder(get_default_context(), name='test_window_recorder', sink=slow_sink)
    try:
        recorder.acknowledge(tuple(TOPICS), 4 * ts_ns)
        for name in ('plant', 'controller', 'reference'):
            argv = node_cmd(f'{name}_node', '--params-file', str(path))
            if name == 'plant':
                argv += ['-p', 'lockstep.record_window:=8']
            procs.start(name, argv, env=ros_env)

        def logs() -> str:
            return '\n'.join(p.tail() for p in procs.processes.values())
        assert recorder.spin_until(lambda: all(recorder.publisher_count(t) for t in TOPICS)
                                   and recorder.subscriber_count('recorded'), 60), logs()
        assert recorder.set_parameters('plant', {'lockstep.paused': False}, 30) is None, logs()
        assert recorder.spin_until(
            lambda: all(recorder.latest.get(t, -1) >= last_tick * ts_ns for t in TOPICS), 300), \
            (recorder.counts, logs())
        assert recorder.acknowledged >= last_tick // 4 - 2     # acknowledged every 4 ticks
        # the window held the plant back: when it published its diagnostics it was at most 8
        # ticks ahead of its last acknowledgment, which the recorder had sent for ticks it
        # had taken by then
        taken_at = [t for t, _ in taken]
        ahead = [tick - max([-1] + [k for _, k in taken[:bisect.bisect_right(taken_at, sent)]])
                 for sent, tick in reports]
        assert ahead and max(ahead) <= 8 + 1, ahead
    finally:
        recorder.destroy()

    recorder.messages = kept
    seen: dict[str, dict[int, tuple]] = {topic: {} for topic in TOPICS}
    for m in recorder.signal_messages():
        seen[m.topic].setdefault(m.stamp_ns, (m.names, m.values))
    clock = {raw.publish_time_ns for raw in kept if raw.topic == '/clock'}
    expected = run_in_process(params, duration=last_tick * ts_ns / 1e9)
    ticks = range(last_tick + 1)
    assert not [k for k in ticks if k * ts_ns not in clock]
    for topic in HELD_TOPICS:        # one message per change: by zero-order hold
        seen[topic] = per_tick(seen[topic], [k * ts_ns for k in ticks])
    for topic, prefix in TOPICS.items():
        missing = [k for k in ticks if k * ts_ns not in seen[topic]]
        assert not missing, (topic, len(missing), missing[:10])
        for i, name in enumerate(seen[topic][0][0]):
            ros = np.array([seen[topic][k * ts_ns][1][i] for k in ticks])
            np.testing.assert_allclose(ros, expected[f'{prefix}.{name}'][:last_tick + 1],
                                       rtol=0, atol=1e-9, err_msg=f'{prefix}.{name}')
