"""Values that once ended a node are refused with a reason over real DDS, and the
nodes keep running: config/ipdt_pid.yaml in lockstep (plant, controller, reference processes),
the project's ``ros2 param set`` / ``ros2 param load`` as a user types them:

* ``/controller tuning.dead_time 5.0e-324`` (the mdp rule's k1·To underflowed to 0: a
  ZeroDivisionError in the pre-set callback ended the controller);
* ``/plant real_time_factor 1e-12`` and ``5e-324`` (the tick timer's period overflowed);
* ``/controller`` loaded with ``tuning.rule none, ti 1e-170, td 1e-170`` (√(ti·td) underflowed
  to a zero tracking time);

and ``real_time_factor: 1.0e-300`` in a params file is one line on stderr (exit 2), no
traceback.
"""
from __future__ import annotations

import subprocess

from rosgraph_msgs.msg import Clock
from support import CONFIG
from support.ros2cli import ros2, ros2_parallel

from tank_control.core import params_file

NODES = ('plant', 'controller', 'reference')


def _clock_after(probe, stamp_ns: int, timeout: float = 60.0) -> int:
    """The first /clock stamp [ns] after ``stamp_ns`` (the loop moves)."""
    seen: list[int] = []
    sub = probe.node.create_subscription(
        Clock, '/clock', lambda m: seen.append(m.clock.sec * 10 ** 9 + m.clock.nanosec), 10)
    try:
        assert probe.wait_for(lambda: any(s > stamp_ns for s in seen), timeout), seen[-3:]
        return max(seen)
    finally:
        probe.node.destroy_subscription(sub)


def test_crash_values_are_refused_and_the_nodes_survive(procs, probe, ros_env, node_cmd,
                                                        tmp_path):
    path = CONFIG / 'ipdt_pid.yaml'
    started = {name: procs.start(name, node_cmd(f'{name}_node', '--params-file', str(path)),
                                 env=ros_env) for name in NODES}
    assert probe.wait_for(lambda: {'plant', 'controller', 'reference'}
                          <= set(probe.node.get_node_names()), 60)
    t0 = _clock_after(probe, 0)

    load = tmp_path / 'underflow.yaml'
    params_file.write({'controller': {'tuning.rule': 'none', 'ti': 1e-170, 'td': 1e-170}}, load)
    dead_time, rtf, rtf_denormal, loaded = ros2_parallel(
        ros_env,
        ('param', 'set', '/controller', 'tuning.dead_time', '5.0e-324'),
        ('param', 'set', '/plant', 'real_time_factor', '1e-12'),
        ('param', 'set', '/plant', 'real_time_factor', '5e-324'),
        ('param', 'load', '/controller', str(load)))

    assert dead_time.returncode != 0
    assert 'tuning.dead_time' in dead_time.stderr
    assert 'below the smallest magnitude 1e-06; allowed 0 or [1e-06, 1e+12]' in dead_time.stderr
    for result in (rtf, rtf_denormal):
        assert result.returncode != 0
        assert 'real_time_factor' in result.stderr
        assert 'allowed 0 or [0.001, 1e+06]' in result.stderr, result.stderr
    assert 'below the smallest magnitude 1e-06' in loaded.stdout + loaded.stderr, loaded

    for name, proc in started.items():
        assert proc.returncode is None, f'{name} ended:\n{proc.tail()}'
    got = ros2(ros_env, 'param', 'get', '/controller', 'tuning.dead_time')
    assert got.stdout.strip() == 'Double value is: 5.0', got.stderr
    got = ros2(ros_env, 'param', 'get', '/plant', 'real_time_factor')
    assert got.stdout.strip() == 'Double value is: 1.0', got.stderr
    got = ros2(ros_env, 'param', 'get', '/controller', 'ti')
    assert got.stdout.strip() != 'Double value is: 1e-170', got.stdout
    _clock_after(probe, t0)           # the loop still runs


def test_a_denormal_real_time_factor_in_a_params_file_is_one_line(node_cmd, ros_env,
                                                                   tmp_path):
    sections = params_file.read(CONFIG / 'ipdt_pid.yaml')
    sections['plant']['real_time_factor'] = 1.0e-300
    path = params_file.write(sections, tmp_path / 'slow.yaml')
    out = subprocess.run(node_cmd('plant_node', '--params-file', str(path)),
                         capture_output=True, text=True, timeout=120, env=ros_env, check=False)
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert 'Traceback' not in out.stderr and 'File "' not in out.stderr, out.stderr
    lines = [line for line in out.stderr.splitlines() if not line.startswith('[ERROR] [')]
    assert len(lines) == 1, out.stderr
    assert 'real_time_factor: 1e-300 is non-zero and below the smallest magnitude' in lines[0]
