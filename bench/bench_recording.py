"""run.mcap of an in-process run: direct CDR encoding against rclpy's serializer, in one run.

An in-process run writes its trace as the messages a lockstep run carries (``/clock`` and four
``sensor_msgs/JointState`` per tick; ``harness/recording.py`` ``write_trace``). Two encoders,
interleaved repeat by repeat so both see the same machine:

* ``JointStateCdr`` / ``clock_cdr`` (this tree): the CDR bytes packed with ``struct``;
* the baseline, what the harness did before: build the ROS message object and call
  ``rclpy.serialization.serialize_message`` (the same bytes; test_harness_outputs.py checks the
  round trip).

Reported: µs per JointState message (2 channels) and rows (ticks) per second of writing a whole
trace to run.mcap, medians (min–max) of ``--repeats`` and the ratio of the medians.

    .venv/bin/python bench/bench_recording.py [--repeats 5] [--messages 20000]
                                              [--scenario config/scenarios/tf_002_pi.yaml]

``--chunks [TICKS_PER_S]`` measures instead what the recording's flushing costs (a hard kill
loses at most ``stream.FLUSH_PERIOD``): rows/s and bytes per row of writing the trace with the
writer's 1 MiB chunks and no flush (before) against ``recording.CHUNK_SIZE`` chunks ended
every ``FLUSH_PERIOD`` of a run going at TICKS_PER_S (default 1000, a lockstep run's pace:
a flush every 500 rows), interleaved repeat by repeat.
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def serialized_trace_messages():
    """The baseline class: ``TraceMessages`` with every message built and serialized by rclpy
    (made on first use: the module imports without the package's heavy imports)."""
    from tank_control.harness.recording import TraceMessages

    class SerializedTraceMessages(TraceMessages):
        def add(self, row) -> None:
            from rclpy.serialization import serialize_message
            from rosgraph_msgs.msg import Clock
            from sensor_msgs.msg import JointState

            from tank_control.harness.recording import RawMessage
            t_ns = self.t0_ns + int(round(float(row[self._t]) * 1e9))
            sec, nanosec = divmod(t_ns, 1_000_000_000)
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = sec, nanosec
            add = self.recording.add
            add(RawMessage('/clock', 'rosgraph_msgs/msg/Clock', serialize_message(clock), t_ns,
                           t_ns))
            for topic, _, columns in self._topics:
                msg = JointState()
                msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
                msg.name = list(self.channels[topic])
                msg.position = [float(row[i]) for i in columns]
                add(RawMessage(topic, 'sensor_msgs/msg/JointState', serialize_message(msg),
                               t_ns, t_ns))
    return SerializedTraceMessages


def per_message(kind: str, count: int) -> float:
    """µs per encoded JointState of 2 channels."""
    from tank_control.harness.recording import JointStateCdr
    names, values = ('h', 'T_out'), (81.0, 33.5)
    if kind == 'cdr':
        encoder = JointStateCdr(names)
        start = time.perf_counter()
        for k in range(count):
            encoder.encode(k, 0, values)
    else:
        from rclpy.serialization import serialize_message
        from sensor_msgs.msg import JointState
        start = time.perf_counter()
        for k in range(count):
            msg = JointState()
            msg.header.stamp.sec = k
            msg.name = list(names)
            msg.position = list(values)
            serialize_message(msg)
    return 1e6 * (time.perf_counter() - start) / count


def whole_trace(kind: str, trace, folder: Path) -> float:
    """Rows per second of writing ``trace`` to a run.mcap."""
    from tank_control.harness.recording import McapRecording, TraceMessages
    cls = TraceMessages if kind == 'cdr' else serialized_trace_messages()
    path = folder / f'{kind}.mcap'
    start = time.perf_counter()
    with McapRecording(path) as recording:
        rows = cls(recording, trace.names)
        for row in zip(*trace.columns.values()):
            rows.add(row)
    elapsed = time.perf_counter() - start
    path.unlink()
    return len(trace) / elapsed


def chunked_trace(flush_rows: int | None, trace, folder: Path) -> tuple[float, float]:
    """Rows per second and bytes per row of writing ``trace`` to a run.mcap: ``flush_rows``
    None = 1 MiB chunks, never flushed (before); else ``CHUNK_SIZE`` chunks flushed every
    ``flush_rows`` rows."""
    from tank_control.harness.recording import McapRecording, TraceMessages
    path = folder / 'chunks.mcap'
    start = time.perf_counter()
    with McapRecording(path, chunk_size=1024 * 1024) if flush_rows is None \
            else McapRecording(path) as recording:
        rows = TraceMessages(recording, trace.names)
        for k, row in enumerate(zip(*trace.columns.values())):
            rows.add(row)
            if flush_rows and k % flush_rows == flush_rows - 1:
                recording.flush()
    elapsed = time.perf_counter() - start
    size = path.stat().st_size
    path.unlink()
    return len(trace) / elapsed, size / len(trace)


def chunks_main(args, trace) -> int:
    from tank_control.harness.stream import FLUSH_PERIOD
    flush_rows = max(1, int(round(args.chunks * FLUSH_PERIOD)))
    results: dict[str, list[tuple[float, float]]] = {}
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for label, rows in (('1 MiB chunks, no flush (before)', None),
                                (f'flushed every {flush_rows} rows (after)', flush_rows)):
                rate, size = chunked_trace(rows, trace, Path(tmp))
                results.setdefault(label, []).append((rate, size))
                print(f'repeat {repeat + 1}: {label}: {rate:.0f} rows/s, {size:.1f} bytes/row',
                      flush=True)
    load_after = os.getloadavg()
    print(f'\nload average (1 min) before {load_before[0]:.2f}, after {load_after[0]:.2f}; '
          f'{args.repeats} repeats, medians (min–max); trace of {Path(args.scenario).name}, '
          f'{len(trace)} rows\n')
    print('| run.mcap written | rows/s | bytes per row |')
    print('|---|---|---|')
    for label, rs in results.items():
        print(f'| {label} | {_median_range([r for r, _ in rs], ".0f")} | '
              f'{_median_range([b for _, b in rs], ".1f")} |')
    return 0


def _median_range(values: list[float], fmt: str) -> str:
    return f'{statistics.median(values):{fmt}} ({min(values):{fmt}}–{max(values):{fmt}})'


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--messages', type=int, default=20000)
    parser.add_argument('--scenario', default=str(REPO / 'config/scenarios/tf_002_pi.yaml'))
    parser.add_argument('--chunks', type=float, nargs='?', const=1000.0, metavar='TICKS_PER_S',
                        help='measure the cost of flushing the recording instead (docstring)')
    args = parser.parse_args()
    from tank_control.core import params_file
    from tank_control.core.scenario import run_in_process
    trace = run_in_process(params_file.read(args.scenario))
    if args.chunks:
        return chunks_main(args, trace)
    load_before = os.getloadavg()
    results: dict[tuple[str, str], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            for kind in ('cdr', 'rclpy'):
                us = per_message(kind, args.messages)
                rate = whole_trace(kind, trace, Path(tmp))
                results.setdefault(('message', kind), []).append(us)
                results.setdefault(('trace', kind), []).append(rate)
                print(f'repeat {repeat + 1}: {kind}: {us:.2f} µs/message, {rate:.0f} rows/s '
                      f'({len(trace)} rows)', flush=True)
    load_after = os.getloadavg()
    print(f'\nload average (1 min) before {load_before[0]:.2f}, after {load_after[0]:.2f}; '
          f'{args.repeats} repeats, medians (min–max); trace of {Path(args.scenario).name}, '
          f'{len(trace)} rows\n')
    print('| measurement | JointStateCdr | rclpy serialize_message | ratio |')
    print('|---|---|---|---|')
    for what, unit, fmt, better_low in (('message', 'µs per JointState message', '.2f', True),
                                        ('trace', 'rows/s writing run.mcap', '.0f', False)):
        cdr, ser = results[(what, 'cdr')], results[(what, 'rclpy')]
        ratio = (statistics.median(ser) / statistics.median(cdr) if better_low
                 else statistics.median(cdr) / statistics.median(ser))
        print(f'| {unit} | {_median_range(cdr, fmt)} | {_median_range(ser, fmt)} | '
              f'{ratio:.1f}x |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
