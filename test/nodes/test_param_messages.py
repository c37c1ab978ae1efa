"""One wording for a refused parameter change on every path (docs/nodes.md, "Parameters"): the
node's own reason, from the spec, whether the change comes from the node itself, through its
``set_parameters`` service or from `ros2 param set`; a name that differs only in case gets the
declared spelling."""
from __future__ import annotations

import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from support import CONFIG
from support.ros2cli import ros2

from tank_control.core.params import ParamSpec, nearest, unknown_reason
from tank_control.nodes.params import ParameterBinding, UnknownParameter

SPECS = (ParamSpec('kp', 1.0, 'proportional gain [-]', min=0.0, max=1e12),
         ParamSpec('ti', 10.0, 'integral time [s]', min=0.0, max=1e12),
         ParamSpec('order', 1, 'model order', min=1, max=2))


@pytest.fixture
def bound(rclpy_session):
    import rclpy
    node = rclpy.create_node('param_messages_test')
    binding = ParameterBinding(node, SPECS)
    yield node, binding
    node.destroy_node()


def test_a_value_out_of_range_is_refused_with_the_specs_reason(bound):
    node, binding = bound
    for name, value in (('kp', -1.0), ('kp', 2e12), ('order', 3)):
        result = node.set_parameters([Parameter(name, value=value)])[0]
        spec = next(s for s in SPECS if s.name == name)
        assert not result.successful
        assert result.reason == spec.check(value)          # not rclpy's "out of range Min:"
    assert node.get_parameter('kp').value == 1.0 and node.get_parameter('order').value == 1
    assert binding.rejected == 3 and binding.take_pending() == {}
    assert node.get_parameter('kp').type_ == Parameter.Type.DOUBLE   # still declared, typed
    assert node.set_parameters([Parameter('kp', value=2.5)])[0].successful
    assert binding.take_pending() == {'kp': 2.5}


def test_the_reason_reaches_a_set_parameters_service_client(bound, probe):
    node, _ = bound
    probe.executor.add_node(node)
    try:
        client = probe.node.create_client(SetParameters,
                                          f'{node.get_fully_qualified_name()}/set_parameters')
        assert probe.wait_for(client.service_is_ready, 30.0)
        request = SetParameters.Request(parameters=[
            ParameterMsg(name='kp', value=Parameter('kp', value=-1.0).get_parameter_value())])
        future = client.call_async(request)
        assert probe.wait_for(future.done, 30.0)
        [result] = future.result().results
        assert result.reason == 'kp: -1 is below the minimum; allowed [0, 1e+12]'
        request = SetParameters.Request(parameters=[
            ParameterMsg(name='Kp', value=Parameter('Kp', value=1.0).get_parameter_value())])
        future = client.call_async(request)
        assert probe.wait_for(future.done, 30.0)
        [result] = future.result().results
        assert not result.successful
        assert result.reason == 'Kp: unknown parameter; did you mean kp?'
    finally:
        probe.executor.remove_node(node)


def test_a_name_differing_in_case_gets_the_declared_spelling(bound):
    node, binding = bound
    with pytest.raises(UnknownParameter, match=r'^Kp: unknown parameter; did you mean kp\?$'):
        node.set_parameters([Parameter('Kp', value=1.0)])
    assert binding.rejected == 1                      # counted as a refusal
    assert nearest('KP', ['kp', 'ki', 'kd']) == 'kp'
    assert unknown_reason('TI', [f'name{i}' for i in range(120)] + ['ti']) == \
        'TI: unknown parameter; did you mean ti?'


def test_ros2_param_set_prints_the_controllers_reason(procs, ros_env, node_cmd):
    procs.start('controller', node_cmd('controller_node', '--params-file',
                                       str(CONFIG / 'ipdt_pid.yaml')), env=ros_env)
    refused = ros2(ros_env, 'param', 'set', '/controller', 'kp', '-1.0', '--timeout', '60')
    assert refused.returncode == 1
    assert refused.stderr.strip() == \
        'Set parameter failed: kp: -1 is below the minimum; allowed [0, 1e+12]'
    typo = ros2(ros_env, 'param', 'set', '/controller', 'Kp', '2.0', '--timeout', '60')
    assert typo.returncode == 1
    assert typo.stderr.strip() == 'Set parameter failed: Kp: unknown parameter; did you mean kp?'
    got = ros2(ros_env, 'param', 'get', '/controller', 'Kp', '--timeout', '60')
    assert got.returncode == 1 and 'did you mean kp?' in got.stderr


def test_a_controller_without_a_plant_says_on_its_console_what_it_waits_for(procs, probe,
                                                                           ros_env):
    """The controller started alone logs (once) what it waits for, as the plant does."""
    import sys
    proc = procs.start('controller', [sys.executable, '-m', 'tank_control.nodes.controller_node',
                                      '--ros-args', '--params-file',
                                      str(CONFIG / 'ipdt_pid.yaml')], env=ros_env)
    assert probe.wait_for(lambda: 'nothing to control yet' in proc.tail(50), 60.0), proc.tail()
    line = next(t for t in proc.tail(50).splitlines() if 'nothing to control yet' in t)
    assert 'waiting for' in line and 'plant_node' in line
    assert probe.wait_for(lambda: False, 1.0) is False       # a diagnostics period later ...
    assert proc.tail(200).count('nothing to control yet') == 1   # ... said once, not repeated
