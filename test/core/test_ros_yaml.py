"""Parameter files mean the same to the nodes (rcl's parser) and to Python tools."""
from __future__ import annotations

from tank_control.core import ros_yaml


def test_scalars_are_read_as_ros_2_reads_them():
    doc = ros_yaml.load("plant:\n  ros__parameters:\n    noise_std: 1e-3\n    flag: y\n    y: 2\n")
    params = doc['plant']['ros__parameters']
    assert params['noise_std'] == 0.001 and isinstance(params['noise_std'], float)
    assert params['flag'] is True          # a value y is a boolean in ROS 2 files
    assert params['y'] == 2                # a key y is a name


def test_dump_quotes_strings_that_would_change_type():
    document = {'reference': {'ros__parameters': {'setpoint.channels': ['y', 'h'], 'eps': '1e-3'}}}
    text = ros_yaml.dump(document)
    assert ros_yaml.load(text) == document


def test_nested_parameter_maps_flatten_to_dotted_names():
    params = ros_yaml.load('setpoint:\n  y:\n    times: [0.0, 5.0]\n  channels: [\'y\']\nkp: 2.0\n')
    assert ros_yaml.flatten(params) == {'setpoint.y.times': [0.0, 5.0], 'setpoint.channels': ['y'],
                                        'kp': 2.0}


#: Strings that rcl's parser (booleans y/yes/on/true/..., strtol/strtod numbers) or YAML 1.1
#: read as something else when written plain.
NOT_PLAIN = ['y', 'Y', 'n', 'N', 'yes', 'No', 'ON', 'off', 'true', 'False', 'inf', 'nan',
             'Infinity', '.inf', '1e5', '0x10', '0x1p3', '010', '1_000', '1:30', '~', 'null',
             '2001-01-01', '', '[', 'a: b']


def test_dump_quotes_every_string_another_reader_would_retype():
    for word in NOT_PLAIN:
        text = ros_yaml.dump({'p': [word]})
        assert f"'{word}'" in text or f"''{word}''" in text, (word, text)
        assert ros_yaml.load(text) == {'p': [word]}, word
    for name in ('T_out', 'F_Cin', 'h', 'b', 'idle', 'first_harmonic'):
        assert ros_yaml.dump({'p': [name]}) == f'p: [{name}]\n'     # names stay plain
