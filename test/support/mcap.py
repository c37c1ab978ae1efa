"""Reading a run's ``run.mcap`` back in tests, with the mcap reader and the ROS 2 decoder."""
from __future__ import annotations

from pathlib import Path


def read_mcap(path: str | Path) -> dict[str, list]:
    """topic → decoded messages, in file order."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    seen: dict[str, list] = {}
    with open(path, 'rb') as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append(msg)
    return seen


def stamps_and_arrivals(path: str | Path, topic: str) -> list[tuple[int, int]]:
    """(header stamp, time the recorder received it) [ns, system clock] of every message of a
    stamped ``topic``, in file order."""
    from mcap.reader import make_reader

    from tank_control.nodes.cdr import cdr_stamp_ns
    with open(path, 'rb') as handle:
        return [(cdr_stamp_ns(msg.data), msg.log_time)
                for _, channel, msg in make_reader(handle).iter_messages()
                if channel.topic.lstrip('/') == topic.lstrip('/')]
