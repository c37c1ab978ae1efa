"""A busy lockstep graph stops cleanly on SIGTERM and SIGINT: every node exits with status 0
and prints no traceback (rclpy's own signal handlers shut the context down under a running
callback: "publisher's context is invalid", [FATAL])."""
from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest
from sensor_msgs.msg import JointState
from support import CONFIG

from tank_control.core import params_file
from tank_control.harness.processes import ProcessGroup
from tank_control.nodes.messages import SIGNAL_QOS

NODES = ('plant', 'controller', 'reference')
ROUNDS = 3
BUSY_TICKS = 300          # ticks seen before the signal: the loop runs flat out


def busy_scenario(tmp_path: Path) -> Path:
    params = params_file.read(CONFIG / 'ipdt_pid.yaml')
    params['plant'].update({'lockstep.paused': False, 'real_time_factor': 0.0})
    return params_file.write(params, tmp_path / 'busy.yaml')


def _wait_or_stack(proc, timeout: float = 20.0) -> int:
    """The exit status; a node still running after ``timeout`` s is sent SIGABRT, and the
    failure shows its threads' stacks (faulthandler, nodes/runtime.py) from its log."""
    try:
        return proc.popen.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.popen.send_signal(signal.SIGABRT)
        try:
            proc.popen.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass
        pytest.fail(f'{proc.name} did not stop within {timeout:g} s of the signal; its '
                    f'stacks on SIGABRT:\n{proc.tail(80)}')


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT], ids=['SIGTERM', 'SIGINT'])
def test_busy_lockstep_nodes_stop_cleanly(sig, ros_env, node_cmd, probe, tmp_path):
    path = busy_scenario(tmp_path)
    seen: list[int] = []
    sub = probe.node.create_subscription(JointState, 'measurement',
                                         lambda m: seen.append(m.header.stamp.sec), SIGNAL_QOS)
    try:
        for round_ in range(ROUNDS):
            with ProcessGroup(tmp_path / f'logs{round_}') as group:
                for name in NODES:
                    group.start(name, node_cmd(f'{name}_node', '--params-file', str(path)),
                                env=ros_env)
                seen.clear()
                logs = lambda: '\n'.join(f'--- {n}\n{p.tail(30)}'   # noqa: E731
                                         for n, p in group.processes.items())
                assert probe.wait_for(lambda: len(seen) >= BUSY_TICKS, 60), logs()
                # every node is inside its answer chain now; signal all, in a rotating order
                order = NODES[round_ % 3:] + NODES[:round_ % 3]
                for name in order:
                    group.processes[name].popen.send_signal(sig)
                codes = {name: _wait_or_stack(group.processes[name]) for name in order}
                assert codes == {name: 0 for name in NODES}, logs()
                for name, proc in group.processes.items():
                    text = proc.log_path.read_text(errors='replace')
                    assert 'Traceback' not in text and 'FATAL' not in text, (name, text[-3000:])
    finally:
        probe.node.destroy_subscription(sub)
