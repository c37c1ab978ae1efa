"""``tank-control recover OUT``: the results of a run whose harness ended without writing them
(SIGKILL, a crash, a power cut), rebuilt from what is on disk.

A run flushes ``run.mcap`` at least every ``stream.FLUSH_PERIOD`` (each flush ends a compressed
chunk), so a harness killed at any moment leaves every message received until a quarter second
before, in whole chunks, followed by at most one chunk cut short; what is missing is the
summary and index a reader seeks by (``mcap``'s ``make_reader`` refuses such a file). Recovery
reads the file record by record, keeps every whole chunk whose data checks out (CRC), drops
the cut tail, and writes:

* ``run.mcap``: the same messages (same topics, schemas, times, order) with summary and index;
* ``trace.csv``: the join of the recovered signal messages (``harness/trace.py``, the rows a run
  writes as it goes: the row of the last measurement is left out, its answers may not have
  come), which reaches further than the trace.csv the run had flushed (it holds rows back
  ``stream.HOLDBACK`` seconds);
* ``metrics.json``: ``"complete": false``, the ``reason``, the metrics of that trace, and
  ``run.recovered`` (what was read and what was dropped);
* ``plot.png``, ``analysis.png`` as a run writes them.

The scenario comes from ``OUT/scenario.yaml`` and the run's name and overrides from the
``tank_control.run`` metadata record at the head of ``run.mcap`` (``recording.RUN_METADATA``).
"""
from __future__ import annotations

import json
import os
import shutil
import struct
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

from tank_control.harness.recording import RUN_METADATA, RawMessage

NS = 1_000_000_000
_MAGIC = b'\x89MCAP0\r\n'
_RECORD_HEAD = struct.Struct('<BQ')        # opcode, length


class RecoverError(RuntimeError):
    """``OUT`` cannot be recovered (one line: why)."""


@dataclass
class PartialRecording:
    """What ``read_partial`` found in a recording."""

    messages: list[RawMessage] = field(default_factory=list)
    schemas: dict[str, bytes] = field(default_factory=dict)     # type name → ros2msg text
    metadata: dict[str, str] = field(default_factory=dict)      # the RUN_METADATA record
    finished: bool = False          # the footer is there: the writer closed the file
    size: int = 0                   # bytes in the file
    read: int = 0                   # bytes of whole records read
    bad_chunks: int = 0             # whole chunks whose data did not check out (skipped)
    orphans: int = 0                # messages of a channel defined in a bad chunk (skipped)
    stopped: str = ''               # why reading ended before the footer ('' at the footer)


def read_partial(path: Path) -> PartialRecording:
    """Every message of the whole, intact chunks of an MCAP file, in file order, whether or not
    the writer finished it."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Chunk, Message, Metadata, Schema
    from mcap.stream_reader import breakup_chunk

    data = path.read_bytes()
    found = PartialRecording(size=len(data))
    if data[:len(_MAGIC)] != _MAGIC:
        found.stopped = ('empty file' if not data else 'no MCAP magic at the start')
        return found
    channels: dict[int, tuple[str, int]] = {}     # channel id → (topic, schema id)
    schema_names: dict[int, str] = {}

    def take(record: Any) -> None:
        if isinstance(record, Schema):
            schema_names[record.id] = record.name
            found.schemas.setdefault(record.name, bytes(record.data))
        elif isinstance(record, Channel):
            channels[record.id] = (record.topic, record.schema_id)
        elif isinstance(record, Message):
            if record.channel_id not in channels:    # its channel was in a bad chunk
                found.orphans += 1
                return
            topic, schema_id = channels[record.channel_id]
            found.messages.append(RawMessage(topic, schema_names.get(schema_id, ''),
                                             bytes(record.data), record.log_time,
                                             record.publish_time))

    offset = found.read = len(_MAGIC)
    while True:
        if offset + _RECORD_HEAD.size > len(data):
            found.stopped = 'the file ends inside a record' if offset < len(data) else \
                'the file ends without a summary'
            break
        opcode, length = _RECORD_HEAD.unpack_from(data, offset)
        end = offset + _RECORD_HEAD.size + length
        if end > len(data):
            found.stopped = 'the file ends inside a record (cut short)'
            break
        stream = ReadDataStream(BytesIO(data[offset + _RECORD_HEAD.size:end]))
        try:
            if opcode == Opcode.CHUNK:
                try:
                    records = breakup_chunk(Chunk.read(stream), validate_crc=True)
                except Exception:          # noqa: BLE001 - zstd, CRC or layout: a bad chunk
                    found.bad_chunks += 1
                    records = []
                for record in records:
                    take(record)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                take((Schema if opcode == Opcode.SCHEMA else Channel).read(stream))
            elif opcode == Opcode.MESSAGE:
                take(Message.read(stream, length))
            elif opcode == Opcode.METADATA:
                record = Metadata.read(stream)
                if record.name == RUN_METADATA:
                    found.metadata = dict(record.metadata)
            elif opcode == Opcode.FOOTER:
                found.finished = True
                offset = end
                found.read = offset
                break
        except Exception as exc:           # noqa: BLE001 - a record that does not parse
            found.stopped = f'a record that does not parse at byte {offset} ({exc})'
            break
        offset = end
        found.read = offset
    return found


def _writing_run(out: Path) -> str | None:
    """The run (pid, output) that holds a domain's run lock on this host with ``out`` as its
    output directory, if it still runs (``domains.lock_run`` writes the owner)."""
    from tank_control.harness.domains import RUN_LOCK_DIR
    target = str(out.resolve())
    for lock in sorted(RUN_LOCK_DIR.glob('domain-*.lock')) if RUN_LOCK_DIR.is_dir() else ():
        try:
            text = lock.read_text().strip()
        except OSError:
            continue
        head, _, owner = text.partition(', output ')
        if owner != target or not head.startswith('pid '):
            continue
        try:
            pid = int(head[4:])
            os.kill(pid, 0)
        except (ValueError, ProcessLookupError):
            continue
        except PermissionError:
            pass                                # alive, another user's
        return f'pid {pid}'
    return None


def recover(out: str | Path, force: bool = False) -> tuple[Any, PartialRecording]:
    """Rebuild ``run.mcap``, ``trace.csv``, ``metrics.json`` (and the plots) of the run in
    ``out`` (module docstring); return the ``RunResult`` and what was read. ``RecoverError``
    for a directory that holds no run, a run still going, or one that finished its results
    (``force``: rebuild those too)."""
    from tank_control.harness import runner
    from tank_control.harness.scenario_file import (
        Scenario,
        ScenarioError,
        load_scenario,
    )
    from tank_control.harness.stream import RecordingStream
    from tank_control.harness.trace import HELD_IN_LOCKSTEP

    out = Path(out)
    path = out / 'run.mcap'
    if not (out / 'scenario.yaml').is_file() or not path.is_file():
        raise RecoverError(f'{out}: no scenario.yaml and run.mcap there: not the output '
                           'directory of a run')
    holder = _writing_run(out)
    if holder:
        raise RecoverError(f'{out}: a run is still writing there ({holder}); wait for it to end')
    if (out / 'metrics.json').is_file() and not force:
        raise RecoverError(f'{out}: metrics.json is there: the run wrote its results; nothing '
                           'to recover (--force rebuilds them from run.mcap)')
    found = read_partial(path)
    meta = found.metadata
    try:
        loaded = load_scenario(out / 'scenario.yaml')
    except ScenarioError:
        loaded = load_scenario(out / 'scenario.yaml', check_nodes=False)   # other node programs
    scenario = Scenario(Path(meta.get('path', loaded.path)), loaded.sections,
                               tuple(json.loads(meta.get('overrides', '[]'))))
    config = scenario.harness
    mode = meta.get('mode', config.clock_mode)
    join_mode = 'lockstep' if mode == 'in_process' else mode
    plant = scenario.params('plant')
    sample_time = plant.get('sample_time')
    sample_time = (float(sample_time) if isinstance(sample_time, (int, float))
                   and not isinstance(sample_time, bool) and sample_time > 0 else None)
    tick_ns = round(sample_time * NS) if sample_time else None
    origin = 0
    if join_mode == 'wall':
        origins = [m.publish_time_ns for m in found.messages if m.topic.lstrip('/') == 'time_origin']
        measured = [m.publish_time_ns for m in found.messages
                    if m.topic.lstrip('/') == 'measurement']
        origin = origins[-1] if origins else (measured[0] if measured else 0)

    work = out / '.recover'
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    stream = RecordingStream(work, lambda: origin, round(config.duration * NS), tick_ns,
                             runner.due_periods(scenario, join_mode, tick_ns), sample_time,
                             held=HELD_IN_LOCKSTEP if join_mode == 'lockstep' else (),
                             metadata={**meta, 'recovered': 'true'} if meta else None)
    stream.outputs.recording.schema_data.update(found.schemas)
    counts: dict[str, int] = {}
    for msg in found.messages:
        stream.on_message(msg)
        key = msg.topic.lstrip('/')
        counts[key] = counts.get(key, 0) + 1
    trace = stream.close(complete=False)
    old_rows = _rows(out / 'trace.csv')
    kept_old = old_rows > len(trace)          # cannot happen (trace.csv lags): then keep it
    os.replace(work / 'run.mcap', path)
    if not kept_old:
        os.replace(work / 'trace.csv', out / 'trace.csv')
    shutil.rmtree(work, ignore_errors=True)
    if kept_old:
        from tank_control.core.trace import Trace
        trace = Trace.read_csv(out / 'trace.csv')
        trace.late = stream.joiner.late
    if join_mode != 'wall' or origin:
        stream.stamps.start_ns = origin
    sampling = stream.stamps.result()
    if join_mode == 'wall':
        sampling['max_jitter'] = stream.arrivals.result()['max_jitter']
    measured_at = [m.log_time_ns for m in found.messages if m.topic.lstrip('/') == 'measurement']
    wall = ((found.messages[-1].log_time_ns - measured_at[0]) / NS) if measured_at else 0.0
    ticks = len(trace)
    run_info: dict[str, Any] = {
        'mode': mode,
        'real_time_factor': config.real_time_factor,
        'sim_duration': float(trace.t[-1]) if ticks else 0.0,
        'wall_time': wall,
        'ticks': ticks,
        'ticks_per_s': ticks / wall if wall > 0 else 0.0,
        'missed_samples': sampling['missed_samples'],
        'late_samples': int(sum(trace.late.values())),
        'late_by_signal': trace.late,
        'max_jitter': sampling['max_jitter'],
        'messages': counts,
        'messages_after_row_written': stream.joiner.after_written,
        'unreadable_messages': stream.unreadable,
        'recovered': {
            'messages': len(found.messages),
            'bytes': found.size,
            'bytes_dropped': found.size - found.read,
            'bad_chunks': found.bad_chunks,
            'messages_without_channel': found.orphans,
            'file_was_finished': found.finished,
            'stopped': found.stopped or None,
            'trace_rows_on_disk': old_rows,
            'last_measurement': (stream.last_measurement - origin) / NS
            if stream.last_measurement is not None else None,
            'wall_time': 'from the arrival times in run.mcap (first measurement to last message)',
        },
    }
    events = harness_events(found.messages, origin)
    if events:
        run_info['harness_events'] = events
    states = stream.states.result()
    if states:
        run_info['controller_states'] = states
    if stream.modes.changes:
        run_info['controller_modes'] = stream.modes.result()
    reason = ('the harness ended without writing its results (killed or crashed); recovered '
              'from run.mcap by tank-control recover')
    files = {'trace': out / 'trace.csv', 'recording': path}
    (out / 'metrics.json').unlink(missing_ok=True)
    result = runner.finish(scenario, out, trace, run_info, {}, files, reason)
    return result, found


def harness_events(messages: list[RawMessage], origin: int) -> list[dict[str, Any]]:
    """The harness's own events in a recording (``runner.HARNESS_EVENTS``: a node restarted),
    ``{'time': s of plant time, 'text': ...}``: a recovered run's ``run.restarts`` in words."""
    from rcl_interfaces.msg import Log
    from rclpy.serialization import deserialize_message

    from tank_control.harness.runner import HARNESS_EVENTS
    events = []
    for msg in messages:
        if msg.topic == HARNESS_EVENTS:
            try:
                text = deserialize_message(msg.data, Log).msg
            except Exception:                  # noqa: BLE001 - unreadable bytes: in words
                text = f'(unreadable harness event, {len(msg.data)} bytes)'
            events.append({'time': (msg.publish_time_ns - origin) / NS, 'text': text})
    return events


def _rows(path: Path) -> int:
    """Rows of a trace.csv after its header (0 without the file)."""
    try:
        return max(path.read_bytes().count(b'\n') - 1, 0)
    except OSError:
        return 0
