"""nodes/params.py: specs → declared, validated ROS 2 parameters (in-process rclpy node)."""
from __future__ import annotations

import math

import pytest
from rcl_interfaces.msg import ParameterType
from rclpy.parameter import Parameter

from tank_control.core.params import ParamSpec
from tank_control.nodes.params import ParameterBinding, ParameterError

SPECS = (
    ParamSpec('mode_name', 'pid', 'controller kind', choices=('pid', 'pi'), read_only=True),
    ParamSpec('kp', 1.0, 'proportional gain [-]', min=0.0, max=100.0),
    ParamSpec('u_min', 0.0, 'lower output limit', min=-1e3, max=1e3),
    ParamSpec('u_max', 10.0, 'upper output limit', min=-1e3, max=1e3),
    ParamSpec('order', 1, 'model order', min=1, max=2),
    ParamSpec('weights', [1.0, 2.0], 'per-output weights', min=0.0),
    ParamSpec('tuning.factor', 0.0, '0 = hand tuning; > 0: ki = factor * kp', min=0.0, max=10.0),
    ParamSpec('ki', 0.0, 'integral gain [1/s]', min=0.0, max=1e3),
)


def limits_ordered(values, changed=frozenset()):
    if not values['u_min'] < values['u_max']:
        return f"u_min: {values['u_min']:g} must be below u_max {values['u_max']:g}"
    return None


def derive_ki(values, changed):
    """A stand-in for tuning: with factor > 0, ki follows kp."""
    if values['tuning.factor'] > 0:
        return {'ki': values['tuning.factor'] * values['kp']}
    return {}


@pytest.fixture
def make_node(rclpy_session):
    import rclpy
    nodes = []

    def build(overrides=()):
        node = rclpy.create_node(f'params_test_{len(nodes)}', parameter_overrides=list(overrides))
        nodes.append(node)
        binding = ParameterBinding(node, SPECS, cross_check=limits_ordered, derive=derive_ki)
        return node, binding
    yield build
    for node in nodes:
        node.destroy_node()


def test_declared_with_descriptors_ranges_and_read_only(make_node):
    node, _ = make_node()
    kp = node.describe_parameter('kp')
    assert kp.description == 'proportional gain [-]'
    span = kp.floating_point_range[0]
    assert (span.from_value, span.to_value) == (0.0, 100.0)
    order = node.describe_parameter('order')
    assert (order.integer_range[0].from_value, order.integer_range[0].to_value) == (1, 2)
    assert node.describe_parameter('mode_name').read_only
    assert 'pid, pi' in node.describe_parameter('mode_name').additional_constraints
    weights = node.describe_parameter('weights')   # one-sided: [0, inf] stated in the text
    assert '[0, inf]' in weights.additional_constraints
    assert node.get_parameter('kp').type_ == Parameter.Type.DOUBLE


def test_integer_for_double_accepted_in_file_and_at_runtime(make_node):
    node, binding = make_node([Parameter('kp', value=2), Parameter('weights', value=[3, 4])])
    assert node.get_parameter('kp').value == 2.0
    assert node.get_parameter('kp').type_ == Parameter.Type.DOUBLE
    assert list(node.get_parameter('weights').value) == [3.0, 4.0]
    result = node.set_parameters([Parameter('kp', value=5)])[0]
    assert result.successful, result.reason
    assert node.get_parameter('kp').type_ == Parameter.Type.DOUBLE
    assert binding.values['kp'] == 5.0 and isinstance(binding.values['kp'], float)
    assert binding.take_pending() == {'kp': 5.0}
    assert binding.take_pending() == {}


def test_out_of_range_rejected_with_reason_and_nothing_pending(make_node):
    node, binding = make_node()
    result = node.set_parameters([Parameter('kp', value=-1.0)])[0]
    assert not result.successful
    assert 'kp' in result.reason and '100' in result.reason
    assert node.get_parameter('kp').value == 1.0
    assert binding.take_pending() == {}
    for bad in (math.nan, math.inf):
        assert not node.set_parameters([Parameter('u_max', value=bad)])[0].successful
    result = node.set_parameters([Parameter('weights', value=[1.0, -1.0])])[0]
    assert not result.successful and 'weights' in result.reason and 'minimum' in result.reason


def test_wrong_type_rejected_with_our_reason_and_type_kept(make_node):
    node, binding = make_node()
    result = node.set_parameters([Parameter('kp', value='abc')])[0]
    assert not result.successful
    assert result.reason.startswith('kp:') and 'allowed [0, 100]' in result.reason
    assert node.describe_parameter('kp').type == ParameterType.PARAMETER_DOUBLE
    assert not node.set_parameters([Parameter('order', value=1.5)])[0].successful
    assert binding.rejected == 2


def test_relation_rejected_then_atomic_change_accepted(make_node):
    node, binding = make_node()
    result = node.set_parameters([Parameter('u_min', value=10.0)])[0]
    assert not result.successful and 'u_min' in result.reason and 'u_max' in result.reason
    both = node.set_parameters_atomically([Parameter('u_max', value=20.0),
                                           Parameter('u_min', value=10.0)])
    assert both.successful, both.reason
    assert binding.take_pending() == {'u_min': 10.0, 'u_max': 20.0}


def test_read_only_rejected(make_node):
    node, _ = make_node()
    result = node.set_parameters([Parameter('mode_name', value='pi')])[0]
    assert not result.successful and 'mode_name' in result.reason


def test_derived_values_written_back_with_the_change(make_node):
    node, binding = make_node([Parameter('tuning.factor', value=0.5), Parameter('kp', value=4.0)])
    assert node.get_parameter('ki').value == 2.0                     # at start-up
    assert node.set_parameters([Parameter('kp', value=6.0)])[0].successful
    assert node.get_parameter('ki').value == 3.0                     # with the change
    assert binding.take_pending() == {'kp': 6.0, 'ki': 3.0}


def test_bad_start_up_value_raises_naming_the_parameter(make_node):
    with pytest.raises(ParameterError, match=r'kp: .*allowed \[0, 100\]'):
        make_node([Parameter('kp', value=200.0)])
    with pytest.raises(ParameterError, match='u_min'):
        make_node([Parameter('u_min', value=50.0)])


def test_node_writes_results_including_read_only_without_pending(make_node):
    node, binding = make_node()
    result = binding.write({'mode_name': 'pi', 'kp': 7})
    assert result.successful, result.reason
    assert node.get_parameter('mode_name').value == 'pi' and node.get_parameter('kp').value == 7.0
    assert binding.take_pending() == {}
    assert node.describe_parameter('mode_name').read_only            # still read-only for users
    assert not node.set_parameters([Parameter('mode_name', value='pid')])[0].successful
    assert not binding.write({'kp': 1000.0}).successful              # validated all the same
