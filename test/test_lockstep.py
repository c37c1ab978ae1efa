"""Lockstep: plant + PID controller + reference in three processes == core/loop.py to 1e-9."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from tank_control.core.loop import Trace
from tank_control.core.scenario import read_params_file, run_in_process
from tank_control.nodes.messages import SIGNAL_QOS, from_joint_state

REPO = Path(__file__).resolve().parents[1]
TOPICS = {'measurement': 'y', 'setpoint': 'r', 'manipulated': 'u', 'disturbance': 'd'}


def scenario(tmp_path: Path) -> tuple[dict, Path]:
    """config/ipdt_pid.yaml, shortened, with measurement noise (same seeded draws in both)."""
    params = read_params_file(REPO / 'config' / 'ipdt_pid.yaml')
    # Paced at 20 x real time (200 ticks/s): the recorder in this test process must keep up
    # with four topics whose writers keep only the last 10 samples.
    params['plant'].update({'noise_std': [0.01], 'seed': 7, 'lockstep.paused': True,
                            'real_time_factor': 20.0})
    params['reference'].update({'setpoint.y.times': [0.0, 1.0], 'setpoint.y.values': [0.0, 1.0],
                                'setpoint.y.ramp_rate': 0.5,
                                'disturbance.v.times': [0.0, 12.0],
                                'disturbance.v.values': [0.0, -0.1]})
    params['controller']['sample_time'] = 0.2     # every second plant tick: holds in between
    path = tmp_path / 'scenario.yaml'
    nodes = ('plant', 'controller', 'reference')
    # JSON is YAML with quoted strings (ROS 2 reads an unquoted y as a boolean).
    path.write_text(json.dumps({n: {'ros__parameters': params[n]} for n in nodes}))
    return params, path


def test_lockstep_ros_run_equals_the_in_process_loop(procs, ros_env, node_cmd, probe, tmp_path):
    params, path = scenario(tmp_path)
    ts_ns, last_tick = 100_000_000, 200          # 20 s of simulated time
    seen: dict[str, dict[int, tuple]] = {topic: {} for topic in TOPICS}
    duplicates_differ = []

    def record(topic):
        def callback(msg):
            stamp, names, values = from_joint_state(msg)
            entry = (names, values)
            if seen[topic].setdefault(stamp, entry) != entry:
                duplicates_differ.append((topic, stamp))
        return callback
    subs = [probe.node.create_subscription(JointState, topic, record(topic), SIGNAL_QOS)
            for topic in TOPICS]
    for name in ('plant', 'controller', 'reference'):
        procs.start(name, node_cmd(f'{name}_node', '--params-file', str(path)), env=ros_env)
    # Every publisher matched by the recorder before tick 0 (the plant is paused).
    assert probe.wait_for(lambda: all(s.get_publisher_count() for s in subs), 30), \
        '\n'.join(p.tail() for p in procs.processes.values())
    client = probe.node.create_client(SetParameters, '/plant/set_parameters')
    assert probe.wait_for(client.service_is_ready, 20)
    future = client.call_async(SetParameters.Request(
        parameters=[Parameter('lockstep.paused', value=False).to_parameter_msg()]))
    assert probe.wait_for(future.done, 10) and future.result().results[0].successful

    def done():
        return all(last_tick * ts_ns in seen[t] for t in TOPICS)
    assert probe.wait_for(done, 60), \
        ({t: len(v) for t, v in seen.items()}, '\n'.join(p.tail() for p in procs.processes.values()))
    assert not duplicates_differ   # re-sent ticks were answered identically

    expected = run_in_process(params, duration=last_tick * ts_ns / 1e9)
    columns = {'t': [k * ts_ns / 1e9 for k in range(last_tick + 1)]}
    for topic, prefix in TOPICS.items():
        missing = [k for k in range(last_tick + 1) if k * ts_ns not in seen[topic]]
        assert not missing, (topic, missing[:5])
        names = seen[topic][0][0]
        for i, name in enumerate(names):
            columns[f'{prefix}.{name}'] = [seen[topic][k * ts_ns][1][i]
                                           for k in range(last_tick + 1)]
    ros = Trace({name: np.asarray(v, dtype=float) for name, v in columns.items()})
    assert set(ros.names) == set(expected.names)
    diff = ros.max_abs_difference(expected)
    assert max(diff.values()) <= 1e-9, diff
    # The run is not trivial: setpoint ramp, controller action, noise, disturbance all present.
    assert expected['r.y'][-1] == 1.0 and expected['d.v'][-1] == -0.1
    assert np.ptp(expected['u.u']) > 0.1 and np.std(np.diff(expected['y.y'][:10])) > 1e-3
