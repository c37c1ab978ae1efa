"""The nodes' direct CDR encoding and decoding of signal messages (nodes/cdr.py) is the message
rclpy serializes and reads: the nodes publish these bytes and take their inputs raw."""
from __future__ import annotations

import math

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.nodes.cdr import JointStateCdr, cdr_stamp_ns, clock_cdr_ns, signal_from_cdr
from tank_control.nodes.messages import parse_signal, to_joint_state

CASES = [((), ''), (('y',), '0123456789abcdef'), (('h', 'T_out'), 'a'),
         (('F_H', 'F_Cin', 'x'), 'abc'), (('abcd', 'e'), ''), (('u',), 'session-xy')]


@pytest.mark.parametrize('names, frame_id', CASES)
def test_an_encoded_signal_is_the_message_rclpy_reads(names, frame_id):
    values = [math.pi * (i + 1) for i in range(len(names))]
    data = JointStateCdr(names, frame_id).encode_ns(12_345_678_901, values)
    msg = deserialize_message(data, JointState)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 345_678_901)
    assert (msg.header.frame_id, tuple(msg.name), list(msg.position)) == (frame_id, names, values)
    assert (list(msg.velocity), list(msg.effort)) == ([], [])


@pytest.mark.parametrize('names, frame_id', CASES)
def test_a_signal_taken_raw_reads_as_the_message(names, frame_id):
    values = [-1.5 * (i + 1) for i in range(len(names))]
    msg = to_joint_state(7 * 10**9 + 3, names, values)
    msg.header.frame_id = frame_id
    msg.velocity = [1.0] * len(names)          # fields the nodes do not read are skipped
    data = serialize_message(msg)
    assert signal_from_cdr(data) == (7 * 10**9 + 3, frame_id, names, tuple(values))
    assert parse_signal(data) == parse_signal(msg)


def test_non_finite_values_survive_the_encoding():
    data = JointStateCdr(('a', 'b', 'c')).encode_ns(0, [math.nan, math.inf, -math.inf])
    values = signal_from_cdr(data)[3]
    assert math.isnan(values[0]) and values[1:] == (math.inf, -math.inf)


def test_a_malformed_raw_signal_is_refused_in_one_line():
    msg = to_joint_state(0, ['u', 'x'], [1.0])                  # names and positions differ
    with pytest.raises(ValueError, match='2 names but 1 positions'):
        parse_signal(serialize_message(msg))
    with pytest.raises(ValueError, match='repeated channel name'):
        parse_signal(serialize_message(to_joint_state(0, ['u', 'u'], [1.0, 2.0])))
    data = JointStateCdr(('u', 'v')).encode_ns(0, [1.0, 2.0])
    for cut in (3, 10, 20, len(data) - 12):                     # truncated
        with pytest.raises(ValueError, match='malformed CDR'):
            signal_from_cdr(data[:cut])


def test_clock_encoding():
    data = clock_cdr_ns(5 * 10**9 + 7)
    clock = deserialize_message(data, Clock)
    assert (clock.clock.sec, clock.clock.nanosec) == (5, 7)
    assert cdr_stamp_ns(data) == cdr_stamp_ns(serialize_message(clock)) == 5 * 10**9 + 7


def test_an_encoded_time_is_the_message_rclpy_reads():
    """The recorder's acknowledgments (``recorded``, builtin_interfaces/Time) go out as bytes."""
    from builtin_interfaces.msg import Time

    from tank_control.nodes.cdr import time_cdr_ns
    for t_ns in (0, 1, 999_999_999, 12_345_678_901, 2**31 * 10**9 - 1):
        data = time_cdr_ns(t_ns)
        msg = deserialize_message(data, Time)
        assert msg.sec * 10**9 + msg.nanosec == t_ns
        assert data == serialize_message(Time(sec=msg.sec, nanosec=msg.nanosec))
        assert cdr_stamp_ns(data) == t_ns
