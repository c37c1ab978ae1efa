"""The package starts as ROS 2 users expect: nodes start, spin and stop cleanly."""
from __future__ import annotations

import signal

import pytest
from rcl_interfaces.srv import ListParameters


@pytest.mark.parametrize('module', ['plant_node', 'controller_node', 'reference_node'])
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_node_starts_and_stops_cleanly(module, sig, procs, ros_env, node_cmd, probe):
    name = module.removesuffix('_node')
    proc = procs.start(module, node_cmd(module), env=ros_env)
    # The node is up when it answers a service call (over real DDS): a graph entry alone may
    # still be the previous test's node of the same name, not yet seen to leave.
    client = probe.node.create_client(ListParameters, f'/{name}/list_parameters')
    answered = False
    for _ in range(15):          # a request sent before the new server is matched is lost: ask again
        if client.wait_for_service(timeout_sec=2):
            future = client.call_async(ListParameters.Request())
            answered = probe.wait_for(future.done, timeout=2)
            if answered:
                break
    probe.node.destroy_client(client)
    assert answered, proc.tail()
    proc.popen.send_signal(sig)
    assert proc.popen.wait(timeout=20) == 0, proc.tail()
