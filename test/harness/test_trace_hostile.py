"""A recorded signal message with more names than any loop has (issue 30 re-run, found by
bench/hostile_campaign.py --lockstep): kept in run.mcap as received, never in the trace — before,
one `measurement` of 100 000 names made 100 000 trace columns and the harness spent minutes
writing a trace.csv of 160 MB at the end of a 40 s run."""
from __future__ import annotations

from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from tank_control.harness.recording import RawMessage
from tank_control.harness.stream import RecordingStream


def raw(topic: str, k: int, names: list[str], values: list[float]) -> RawMessage:
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 100_000_000, 1_000_000_000)
    msg.name, msg.position = names, values
    return RawMessage('/' + topic, 'sensor_msgs/msg/JointState', serialize_message(msg), k,
                      k * 100_000_000)


def test_a_message_of_100000_names_is_counted_and_left_out_of_the_trace(tmp_path):
    clock = [0.0]
    stream = RecordingStream(tmp_path, lambda: 0, None, 100_000_000, {'u': 200_000_000}, 0.1,
                             holdback=0.0, clock=lambda: clock[0])
    for k in range(20):
        for topic, name, value in (('measurement', 'y', 0.5 * k), ('setpoint', 'y', 1.0),
                                   ('manipulated', 'u', 2.0), ('disturbance', 'v', 0.0)):
            stream.on_message(raw(topic, k, [name], [value]))
        if k == 5:
            stream.on_message(raw('measurement', k, [f'n{i}' for i in range(100_000)],
                                  [1.0] * 100_000))
        clock[0] += 0.1
        stream.advance()
    trace = stream.close()
    assert stream.unreadable == 1
    assert sorted(trace.columns) == ['d.v', 'r.y', 't', 'u.u', 'y.y']
    assert len(trace.columns['t']) >= 19
