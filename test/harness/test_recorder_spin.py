"""The recorder's ``spin_for``: every message that comes within the time, taken in one call into
the executor (the harness's run loop; ``spin_once`` returns after each message), and back when
the time is up (an idle recorder does not block the run loop's checks)."""
from __future__ import annotations

import os
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from sensor_msgs.msg import JointState

from tank_control.harness.recorder import Recorder
from tank_control.harness.trace import SignalMessage
from tank_control.nodes.cdr import JointStateCdr
from tank_control.nodes.messages import SIGNAL_QOS

pytestmark = pytest.mark.ros   # every test here puts a recorder on the graph


def test_spin_for_takes_every_message_that_came_in_one_call_and_returns_on_time():
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ.get('ROS_DOMAIN_ID', '0')))
    recorder = Recorder(context, name='test_spin_for_recorder')
    source = Node('test_spin_for_source', context=context)
    try:
        pub = source.create_publisher(JointState, 'measurement', SIGNAL_QOS)
        assert recorder.spin_until(lambda: recorder.matched_publishers('measurement') > 0
                                   and pub.get_subscription_count() > 0, 20)
        encoder = JointStateCdr(('y',))
        for k in range(8):                       # fewer than the writer's keep-last 10
            pub.publish(encoder.encode_ns(k * 100_000_000, (float(k),)))
        start = time.monotonic()
        recorder.spin_for(0.5)                   # one call: all eight, however they come
        took = time.monotonic() - start
        signals = recorder.signal_messages(('measurement',))
        assert signals == [SignalMessage('measurement', k * 100_000_000, ('y',), (float(k),))
                           for k in range(8)]
        assert recorder.counts['measurement'] == 8
        assert 0.45 <= took < 5.0               # the time given, not the first message only
        start = time.monotonic()
        recorder.spin_for(0.05)                  # idle: back after the time given
        assert 0.04 <= time.monotonic() - start < 2.0
    finally:
        source.destroy_node()
        recorder.destroy()
        rclpy.try_shutdown(context=context)


def test_a_signal_stamped_far_in_the_future_is_not_recorded_and_cannot_end_a_run():
    """sim/lockstep: a measurement stamped an hour past the latest ``/clock`` is refused — not
    recorded, not the latest stamp (the run loop ends a run once the latest measurement reaches
    its duration), counted in ``future.refused`` (metrics ``rejected_future``) — and the
    valid messages after it are recorded. (Before: it was the latest measurement at once.)"""
    from rosgraph_msgs.msg import Clock

    from tank_control.nodes.cdr import clock_cdr_ns
    from tank_control.nodes.messages import CLOCK_QOS
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ.get('ROS_DOMAIN_ID', '0')))
    tick = 100_000_000
    recorder = Recorder(context, name='test_future_recorder', tick_ns=tick)
    source = Node('test_future_source', context=context)
    try:
        pub = source.create_publisher(JointState, 'measurement', SIGNAL_QOS)
        clock = source.create_publisher(Clock, '/clock', CLOCK_QOS)
        assert recorder.spin_until(lambda: recorder.matched_publishers('measurement') > 0
                                   and recorder.matched_publishers('clock') > 0
                                   and pub.get_subscription_count() > 0
                                   and clock.get_subscription_count() > 0, 20)
        encoder = JointStateCdr(('y',))
        clock.publish(clock_cdr_ns(0))
        assert recorder.spin_until(lambda: recorder.counts.get('clock') == 1, 20)
        pub.publish(encoder.encode_ns(0, (0.0,)))
        pub.publish(encoder.encode_ns(3600 * 10**9, (9.0,)))      # an hour ahead
        for k in range(1, 4):
            clock.publish(clock_cdr_ns(k * tick))
            pub.publish(encoder.encode_ns(k * tick, (float(k),)))
        assert recorder.spin_until(lambda: recorder.counts.get('measurement') == 4, 20)
        assert recorder.latest['measurement'] == 3 * tick
        assert [s.stamp_ns for s in recorder.signal_messages(('measurement',))] == \
            [k * tick for k in range(4)]
        assert recorder.future.refused == 1
    finally:
        source.destroy_node()
        recorder.destroy()
        rclpy.try_shutdown(context=context)
