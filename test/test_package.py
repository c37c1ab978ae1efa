"""The package starts as ROS 2 users expect: nodes start, spin and stop cleanly."""
from __future__ import annotations

import signal

import pytest


@pytest.mark.parametrize('module', ['plant_node', 'controller_node', 'reference_node'])
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_node_starts_and_stops_cleanly(module, sig, procs, ros_env, node_cmd, probe):
    name = module.removesuffix('_node')
    proc = procs.start(module, node_cmd(module), env=ros_env)
    # The node is up when it appears in the graph (over real DDS).
    assert probe.wait_for(lambda: name in probe.node.get_node_names(), timeout=20), proc.tail()
    proc.popen.send_signal(sig)
    assert proc.popen.wait(timeout=10) == 0, proc.tail()
