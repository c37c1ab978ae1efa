"""The parameter audit trail (docs/nodes.md, "The parameter audit trail") over real DDS: every
change a node applies — through its set_parameters service (``ros2 param set``, the dashboard,
the harness), derived from another change, or made by the node itself — is one JSON record on
``/parameter_audit`` with the node, the name, the old and the new value and the source; a
refused change leaves none; a harness ROS run records them in run.mcap."""
from __future__ import annotations

import json
import subprocess
import sys

from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python
from std_msgs.msg import String
from support import CONFIG
from support.mcap import read_mcap
from support.ros2cli import ros2

from tank_control.nodes.params import AUDIT_QOS, AUDIT_TOPIC

WAIT = 60.0
PARAMS = str(CONFIG / 'ipdt_pid.yaml')


def controller_values(probe, names):
    client = probe.node.create_client(GetParameters, '/controller/get_parameters')
    try:
        assert probe.wait_for(client.service_is_ready, WAIT)
        future = client.call_async(GetParameters.Request(names=list(names)))
        assert probe.wait_for(future.done, WAIT)
        return {n: parameter_value_to_python(v) for n, v in zip(names, future.result().values)}
    finally:
        probe.node.destroy_client(client)


def test_every_applied_change_is_one_audit_record(procs, ros_env, node_cmd, probe):
    records: list[dict] = []
    probe.node.create_subscription(String, AUDIT_TOPIC,
                                   lambda msg: records.append(json.loads(msg.data)), AUDIT_QOS)
    procs.start('controller', node_cmd('controller_node', '--params-file', PARAMS), env=ros_env)
    before = controller_values(probe, ['u_max', 'tuning.dead_time', 'kp', 'ti', 'td'])
    assert probe.wait_for(lambda: probe.node.count_publishers(AUDIT_TOPIC) >= 1, WAIT)

    done = ros2(ros_env, 'param', 'set', '/controller', 'u_max', '0.5')
    assert done.returncode == 0 and 'Set parameter successful' in done.stdout, done.stderr
    assert probe.wait_for(lambda: any(r['name'] == 'u_max' for r in records), WAIT)
    (u_max,) = [r for r in records if r['name'] == 'u_max']
    assert u_max['node'] == '/controller' and u_max['source'] == 'set_parameters service'
    assert (u_max['old'], u_max['new']) == (before['u_max'], 0.5)
    assert isinstance(u_max['time'], float)

    refused = ros2(ros_env, 'param', 'set', '/controller', 'u_max', 'abc')
    assert refused.returncode != 0 and 'Set parameter failed' in refused.stderr, refused.stderr
    # the tuning rule derives kp, ti, td from the model: each its own record, its cause named
    done = ros2(ros_env, 'param', 'set', '/controller', 'tuning.dead_time', '4.0')
    assert done.returncode == 0, done.stderr
    derived = {'kp', 'ti', 'td'}
    assert probe.wait_for(lambda: derived <= {r['name'] for r in records}, WAIT), records
    after = controller_values(probe, ['kp', 'ti', 'td'])
    by_name = {r['name']: r for r in records}
    assert by_name['tuning.dead_time']['source'] == 'set_parameters service'
    for name in derived:
        assert by_name[name]['source'] == 'derived from tuning.dead_time'
        assert (by_name[name]['old'], by_name[name]['new']) == (before[name], after[name])
    # the refused value left no record: one per applied change
    assert [r['name'] for r in records].count('u_max') == 1


def test_a_harness_run_records_the_audit_trail_in_run_mcap(tmp_path, ros_env):
    """The harness unpauses the lockstep plant through its set_parameters service: that change
    is in run.mcap with the others of the run."""
    out = tmp_path / 'run'
    run = subprocess.run([sys.executable, '-m', 'tank_control.harness.cli', 'run', PARAMS,
                          '--out', str(out), '--duration', '1', '--quiet', '--no-plots'],
                         env=ros_env, capture_output=True, text=True, timeout=600, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    audit = [json.loads(m.data) for m in read_mcap(out / 'run.mcap')[AUDIT_TOPIC]]
    unpaused = [r for r in audit if r['node'] == '/plant' and r['name'] == 'lockstep.paused']
    assert unpaused and unpaused[0]['old'] is True and unpaused[0]['new'] is False
    assert unpaused[0]['source'] == 'set_parameters service'
