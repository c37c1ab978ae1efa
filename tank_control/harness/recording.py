"""``run.mcap``: every topic of a run in the MCAP ``ros2`` profile (CDR messages, ``ros2msg``
schemas), readable by the ``mcap`` / ``mcap-ros2-support`` readers, Foxglove and PlotJuggler.

A ROS run stores the serialized bytes exactly as they came off the wire, written as they
arrive, in compressed chunks of at most ``CHUNK_SIZE`` that the run ends (``flush``) at least
every ``stream.FLUSH_PERIOD``: a harness killed by SIGKILL leaves every chunk ended before, and
``tank-control recover`` (``harness/recover.py``) rebuilds the summary and index. An
in-process run (no ROS graph) writes the trace as the messages a ROS run would
have carried: ``measurement``, ``setpoint``, ``manipulated``, ``disturbance``
(``sensor_msgs/msg/JointState``, one per tick, stamped t_k) and ``/clock``.
"""
from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from tank_control.core.trace import Trace
from tank_control.harness.trace import TOPIC_PREFIX
from tank_control.nodes.cdr import JointStateCdr, clock_cdr  # noqa: F401 (re-exported)

_PRIMITIVES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
               'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'}
_SEPARATOR = '=' * 80
#: Largest chunk [bytes, uncompressed] before the writer ends it on its own (the writer's
#: ``chunk_size``); the run also ends one at every flush. 1 MiB by default: at 1000 lockstep ticks
#: a second (~0.6 MB/s) a hard kill could lose 1.7 s; smaller chunks cost a little compression.
CHUNK_SIZE = 256 * 1024
#: Name of the MCAP metadata record that says which scenario a recording is of (written first,
#: outside the chunks, so a recording cut short still has it).
RUN_METADATA = 'tank_control.run'


@dataclass(frozen=True)
class RawMessage:
    """A serialized message as received: topic, type (``pkg/msg/Name``), CDR bytes, times [ns]."""

    topic: str
    type_name: str
    data: bytes
    log_time_ns: int
    publish_time_ns: int


def message_definition(type_name: str) -> str:
    """The ``ros2msg`` schema text of a type with its dependencies appended (rosbag2 style)."""
    seen: list[str] = []
    main = _read_msg(type_name)
    parts = [main]
    queue = _dependencies(type_name, main)
    while queue:
        dep = queue.pop(0)
        if dep in seen:
            continue
        seen.append(dep)
        text = _read_msg(dep)
        parts.append(f'{_SEPARATOR}\nMSG: {dep}\n{text}')
        queue += _dependencies(dep, text)
    return '\n'.join(parts)


def _msg_path(type_name: str) -> Path:
    """Where the ``.msg`` file of a type is installed (ament prefixes, then this Python's)."""
    package, _, name = type_name.split('/')
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for prefix in (*prefixes, sys.prefix, sys.base_prefix):
        path = Path(prefix) / 'share' / package / 'msg' / f'{name}.msg'
        if path.is_file():
            return path
    raise FileNotFoundError(f'message definition of {type_name} not found under '
                            + ', '.join((*prefixes, sys.prefix)))


def _read_msg(type_name: str) -> str:
    lines = []
    for line in _msg_path(type_name).read_text().splitlines():
        stripped = line.split('#', 1)[0].strip()
        if stripped:
            lines.append(stripped)
    return '\n'.join(lines)


def _dependencies(type_name: str, text: str) -> list[str]:
    """Non-primitive field types of a ``.msg`` text, as ``pkg/msg/Name``."""
    package = type_name.split('/')[0]
    deps = []
    for line in text.splitlines():
        tokens = line.split()
        if len(tokens) < 2 or '=' in tokens[1] or (len(tokens) > 2 and tokens[2].startswith('=')):
            continue                                        # not a field, or a constant
        field_type = re.sub(r'\[.*\]$', '', tokens[0])       # arrays
        field_type = re.sub(r'<=\d+$', '', field_type)        # bounded strings
        if field_type in _PRIMITIVES:
            continue
        if field_type == 'Header':
            deps.append('std_msgs/msg/Header')
        elif '/' in field_type:
            deps.append(f'{field_type.split("/")[0]}/msg/{field_type.split("/")[-1]}')
        else:
            deps.append(f'{package}/msg/{field_type}')
    return deps


class McapRecording:
    """Write raw CDR messages into an MCAP file (context manager). ``metadata``: the
    ``RUN_METADATA`` record (string values), written at once after the header."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None,
                 chunk_size: int = CHUNK_SIZE) -> None:
        self.path = Path(path)
        self._handle = open(self.path, 'wb')
        self._writer = Writer(self._handle, chunk_size=chunk_size,
                              compression=CompressionType.ZSTD)
        self._writer.start(profile='ros2', library='tank_control harness')
        if metadata:
            self._writer.add_metadata(RUN_METADATA, dict(metadata))
        self._handle.flush()
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        #: type name → schema text to register instead of the installed ``message_definition``
        #: (``recover`` keeps a recording's own)
        self.schema_data: dict[str, bytes] = {}
        self.count = 0

    def add(self, msg: RawMessage) -> None:
        channel = self._channels.get(msg.topic)
        if channel is None:
            schema = self._schemas.get(msg.type_name)
            if schema is None:
                data = self.schema_data.get(msg.type_name)
                schema = self._writer.register_schema(
                    name=msg.type_name, encoding=SchemaEncoding.ROS2,
                    data=data if data is not None else message_definition(msg.type_name).encode())
                self._schemas[msg.type_name] = schema
            channel = self._writer.register_channel(topic=msg.topic,
                                                    message_encoding=MessageEncoding.CDR,
                                                    schema_id=schema)
            self._channels[msg.topic] = channel
        self._writer.add_message(channel_id=channel, log_time=msg.log_time_ns,
                                 publish_time=msg.publish_time_ns, data=msg.data, sequence=self.count)
        self.count += 1

    def flush(self) -> None:
        """End the chunk in progress (if it holds a message) and hand everything to the OS: a
        process killed after this leaves every message added so far in the file (without the
        summary until ``close``; ``tank-control recover`` writes it)."""
        if not self._handle.closed:
            self._writer.flush()

    def close(self) -> None:
        """Write the summary and close: a valid file with every message added (also after a
        failure; a harness killed by SIGKILL leaves the chunks flushed so far, without the
        summary: ``tank-control recover`` rebuilds it)."""
        if self._handle.closed:
            return
        try:
            self._writer.finish()
        finally:
            self._handle.close()

    def __enter__(self) -> McapRecording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_raw(path: str | Path, messages: Iterable[RawMessage]) -> Path:
    """Write received messages, in the order given, to ``path``."""
    with McapRecording(path) as recording:
        for msg in messages:
            recording.add(msg)
    return Path(path)


def write_trace(path: str | Path, trace: Trace, t0_ns: int = 0) -> Path:
    """Write a trace as the signal messages (and ``/clock``) a lockstep run would carry."""
    with McapRecording(path) as recording:
        rows = TraceMessages(recording, trace.names, t0_ns)
        for row in zip(*trace.columns.values()):
            rows.add(row)
    return Path(path)


class TraceMessages:
    """Rows of a trace (columns ``names``) written to ``recording`` as the messages a
    lockstep run carries: ``/clock`` and, per tick, ``measurement``, ``setpoint``,
    ``manipulated``, ``disturbance`` (JointState stamped t_k; ``JointStateCdr``)."""

    def __init__(self, recording: McapRecording, names: Sequence[str], t0_ns: int = 0) -> None:
        self.recording = recording
        self.t0_ns = t0_ns
        index = {name: i for i, name in enumerate(names)}
        self._t = index['t']
        self._topics = []
        self.channels: dict[str, list[str]] = {}        # '/topic' -> its channel names
        for topic, prefix in TOPIC_PREFIX.items():
            channels = [n.split('.', 1)[1] for n in names if n.startswith(prefix + '.')]
            if channels or topic == 'disturbance':
                self.channels['/' + topic] = channels
                self._topics.append(('/' + topic, JointStateCdr(channels),
                                     [index[f'{prefix}.{n}'] for n in channels]))

    def add(self, row: Sequence[float]) -> None:
        t_ns = self.t0_ns + int(round(float(row[self._t]) * 1e9))
        sec, nanosec = divmod(t_ns, 1_000_000_000)
        add = self.recording.add
        add(RawMessage('/clock', 'rosgraph_msgs/msg/Clock', clock_cdr(sec, nanosec), t_ns, t_ns))
        for topic, encoder, columns in self._topics:
            add(RawMessage(topic, 'sensor_msgs/msg/JointState',
                           encoder.encode(sec, nanosec, [float(row[i]) for i in columns]),
                           t_ns, t_ns))
