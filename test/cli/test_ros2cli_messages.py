"""In-process pieces of the `ros2` command: YAML ⇄ message, parameter files, hz statistics."""
from __future__ import annotations

import statistics
import time

import pytest
import yaml

from tank_control.core.params_file import nest
from tank_control.core.ros_yaml import flatten
from tank_control.ros2cli.common import CliError
from tank_control.ros2cli.messages import from_yaml, resolve_type, restamp, to_python, to_yaml
from tank_control.ros2cli.param import parameters_from_file, value_from_python
from tank_control.ros2cli.topic import hz_report


def test_nested_messages_arrays_and_time_round_trip():
    pose_array = resolve_type('geometry_msgs/msg/PoseArray')
    text = ('{header: {stamp: {sec: 12, nanosec: 500000000}, frame_id: tank}, '
            'poses: [{position: {x: 1, y: 2.5}}, {orientation: {w: 1}}]}')
    msg = from_yaml(pose_array, text)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 500_000_000)
    assert msg.poses[0].position.y == 2.5 and msg.poses[1].orientation.w == 1.0
    assert isinstance(msg.poses[0].position.x, float)          # YAML 1 into a float64
    # Printed YAML parses back to the same message.
    assert from_yaml(pose_array, to_yaml(msg)) == msg

    imu = from_yaml(resolve_type('sensor_msgs/Imu'),
                    '{orientation_covariance: [1, 0, 0, 0, 2, 0, 0, 0, 3]}')
    assert to_python(imu)['orientation_covariance'] == [1.0, 0, 0, 0, 2.0, 0, 0, 0, 3.0]
    status = from_yaml(resolve_type('diagnostic_msgs/msg/DiagnosticStatus'),
                       '{level: 2, values: [{key: h, value: "12.5"}]}')
    assert to_python(status)['level'] == 2 and status.values[0].value == '12.5'
    raw = from_yaml(resolve_type('std_msgs/msg/UInt8MultiArray'), '{data: [1, 255]}')
    assert to_python(raw)['data'] == [1, 255]
    assert yaml.safe_load(to_yaml(resolve_type('sensor_msgs/msg/JointState')())) == {
        'header': {'stamp': {'sec': 0, 'nanosec': 0}, 'frame_id': ''},
        'name': [], 'position': [], 'velocity': [], 'effort': []}


@pytest.mark.parametrize('type_name, values, words', [
    ('std_msgs/msg/Float64', '{value: 1}', ["'value'", 'data']),
    ('std_msgs/msg/Float64', '{data: text}', ["'data'", 'double']),
    ('sensor_msgs/msg/JointState', '{position: 1.0}', ["'position'", 'list']),
    ('sensor_msgs/msg/JointState', '{header: {stamp: {sec: 1.5}}}', ["'header.stamp.sec'"]),
    ('std_msgs/msg/UInt8', '{data: 300}', ["'data'", '[0, 255]']),
    ('std_msgs/msg/Int8', '{data: -129}', ["'data'", '[-128, 127]']),
    ('std_msgs/msg/Float64', '[1.0]', ['dictionary']),
    ('sensor_msgs/msg/JointState', '{header: now}', ["'header'", "'auto'", "'now'"]),
    ('sensor_msgs/msg/JointState', '{header: {stamp: auto}}', ["'header.stamp'", "'now'"]),
    ('sensor_msgs/msg/JointState', '{header: {stamp: yesterday}}', ["'header.stamp'", "'now'"]),
    ('std_msgs/msg/Float64', '{data: now}', ["'data'", 'double']),
    ('std_msgs/msg/Float64', '{data: [1', ['YAML']),
    ('std_msgs/msg/Nope', '{}', ['std_msgs/msg/Nope']),
    ('nonsense', '{}', ['nonsense']),
])
def test_bad_values_name_the_field(type_name, values, words):
    with pytest.raises(CliError) as error:
        from_yaml(resolve_type(type_name), values)
    message = str(error.value)
    assert '\n' not in message and all(word in message for word in words), message


def test_stamp_keywords_hold_the_wall_clock_and_are_taken_again_for_each_message():
    """ros2cli's: a Header given as ``auto`` (stamp now, frame_id empty) and a Time given as
    ``now``; ``restamp`` sets every one of them again (``topic pub`` before each message)."""
    joint_state = resolve_type('sensor_msgs/msg/JointState')
    stamps: list = []
    before = time.time_ns()
    msg = from_yaml(joint_state, '{header: auto, name: [y], position: [1.0]}', stamps)
    after = time.time_ns()
    stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    assert before <= stamp_ns <= after and msg.header.frame_id == ''
    assert list(msg.name) == ['y'] and len(stamps) == 1
    restamp(stamps, 7_000_000_005)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (7, 5)
    # a Time field (here the header's own stamp, and /clock's) given as now
    stamps = []
    msg = from_yaml(joint_state, '{header: {stamp: now, frame_id: tank}}', stamps)
    assert msg.header.frame_id == 'tank' and msg.header.stamp.sec >= before // 1_000_000_000
    clock = from_yaml(resolve_type('rosgraph_msgs/msg/Clock'), '{clock: now}', stamps)
    restamp(stamps, 3_000_000_000)
    assert msg.header.stamp.sec == 3 and clock.clock.sec == 3 and len(stamps) == 2
    # without a keyword nothing is restamped
    stamps = []
    from_yaml(joint_state, '{header: {stamp: {sec: 1}}}', stamps)
    assert stamps == []


def test_parameter_file_sections_and_coercion(tmp_path):
    assert nest({'a.b': 1, 'a.c': 2, 'd': 3}) == {'a': {'b': 1, 'c': 2}, 'd': 3}
    assert flatten(nest({'a.b': 1, 'a.c.e': 2, 'd': 3})) == {'a.b': 1, 'a.c.e': 2, 'd': 3}
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters: {kp: 1.0, ti: 5.0}\n'
                    '/ns/*:\n  ros__parameters: {kp: 1.5}\n'
                    'plant:\n  ros__parameters: {kp: 2.0, filter: {n: 10}}\n')
    assert parameters_from_file(str(path), '/plant') == {'kp': 2.0, 'ti': 5.0, 'filter.n': 10}
    assert parameters_from_file(str(path), '/ns/plant') == {'kp': 1.5, 'ti': 5.0}
    assert parameters_from_file(str(path), '/plant', use_wildcard=False) == {
        'kp': 2.0, 'filter.n': 10}
    with pytest.raises(CliError, match='does not contain parameters for /other'):
        parameters_from_file(str(path), '/other', use_wildcard=False)

    from rcl_interfaces.msg import ParameterType as T
    assert value_from_python(None, T.PARAMETER_DOUBLE, raw='2').double_value == 2.0
    assert value_from_python(None, T.PARAMETER_DOUBLE, raw='2').type == T.PARAMETER_DOUBLE
    assert list(value_from_python([1, 2.5], T.PARAMETER_DOUBLE_ARRAY).double_array_value) \
        == [1.0, 2.5]
    assert value_from_python(None, T.PARAMETER_INTEGER, raw='2.5').type == T.PARAMETER_DOUBLE
    assert value_from_python(None, T.PARAMETER_STRING, raw='12').string_value == '12'
    assert value_from_python(None, T.PARAMETER_DOUBLE, raw='1e-3').double_value == 0.001
    assert value_from_python(None, T.PARAMETER_STRING, raw='1e-3').string_value == '1e-3'
    assert list(value_from_python(None, T.PARAMETER_DOUBLE_ARRAY, raw='[1, 2.5]')
                .double_array_value) == [1.0, 2.5]
    assert value_from_python([], T.PARAMETER_STRING_ARRAY).type == T.PARAMETER_STRING_ARRAY


def test_hz_report_statistics():
    stamps = [0.0, 0.1, 0.25, 0.3, 0.4]
    intervals = [0.1, 0.15, 0.05, 0.1]
    rate_line, stats = hz_report(stamps).splitlines()
    assert rate_line == f'average rate: {1 / statistics.fmean(intervals):.3f}'
    assert stats == (f'\tmin: 0.050s max: 0.150s std dev: {statistics.pstdev(intervals):.5f}s '
                     'window: 5')
