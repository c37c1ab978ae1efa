"""A run's ``trace.csv`` and ``run.mcap`` written as the run goes: ``RunOutputs`` (the two
files, both flushed every ``FLUSH_PERIOD``) and ``RecordingStream`` (each recorded
message into run.mcap and the trace join; a row is written once a later tick's measurement
arrived ``HOLDBACK`` ago). docs/harness.md, "Interrupted and failed runs". Wall seconds."""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from struct import error as struct_error

from tank_control.core.trace import Trace, TraceWriter
from tank_control.harness.metrics import SamplingStats
from tank_control.harness.recording import McapRecording, RawMessage
from tank_control.harness.loop_modes import TOPIC as MODE_TOPIC
from tank_control.harness.loop_modes import ModeChanges
from tank_control.harness.states import StateChanges
from tank_control.harness.trace import LATE_TOPICS, TOPIC_PREFIX, SignalMessage, TraceJoiner

#: Wall seconds a row waits, after the measurement of a later tick arrived, for late answers.
HOLDBACK = 2.0
#: Wall seconds between flushes of trace.csv and run.mcap (what a harness killed by SIGKILL can
#: lose, with the time between two checks of the run).
FLUSH_PERIOD = 0.25


class RunOutputs:
    """``trace.csv`` and ``run.mcap`` in ``out``, written as the run goes."""

    def __init__(self, out: Path, clock: Callable[[], float] = time.monotonic,
                 metadata: dict[str, str] | None = None) -> None:
        self.trace = TraceWriter(out / 'trace.csv')
        self.recording = McapRecording(out / 'run.mcap', metadata)
        self.clock = clock
        self._last_flush = clock()

    def flush_now_and_then(self) -> None:
        """Flush trace.csv and run.mcap if ``FLUSH_PERIOD`` passed since the last flush."""
        now = self.clock()
        if now - self._last_flush >= FLUSH_PERIOD:
            self._last_flush = now
            self.trace.flush()
            self.recording.flush()

    def close(self) -> Trace:
        """Close both files (valid as far as they go) and return the table."""
        try:
            self.recording.close()
        finally:
            table = self.trace.close()
        return table


def _signal_message(raw: RawMessage) -> SignalMessage:
    from tank_control.harness.recorder import signal_message
    return signal_message(raw)


class RecordingStream:
    """Recorded messages → ``run.mcap`` and ``trace.csv`` (module docstring).

    ``origin()`` gives the plant's time origin [ns] when the first row is written;
    ``t_end_ns``, ``tick_ns``, ``due_ns``, ``held`` as for ``trace.TraceJoiner``; ``sample_time``
    [s] for the sampling statistics; ``clock`` the wall clock of the holdback; ``metadata``
    what run.mcap says of the run (``McapRecording``).
    """

    def __init__(self, out: Path, origin: Callable[[], int], t_end_ns: int | None,
                 tick_ns: int | None, due_ns: Mapping[str, int], sample_time: float | None,
                 holdback: float = HOLDBACK, clock: Callable[[], float] = time.monotonic,
                 held: Iterable[str] = (), metadata: dict[str, str] | None = None) -> None:
        self.outputs = RunOutputs(out, clock, metadata)
        self.joiner = TraceJoiner(self._on_row, origin, t_end_ns, tick_ns, due_ns, held)
        self.holdback = holdback
        self.clock = clock
        self.measurements: deque[tuple[float, int]] = deque()   # (arrival, stamp) not yet safe
        self.horizon = float('-inf')
        self.stamps = SamplingStats(sample_time)         # of the rows written
        self.arrivals = SamplingStats(sample_time)       # of their measurements' arrivals
        self.arrival_of: dict[int, int] = {}             # measurement stamp → arrival [ns]
        self.unreadable = 0
        self.last_measurement: int | None = None         # largest measurement stamp [ns]
        self.trace: Trace | None = None
        self.states = StateChanges()                     # the controller's state machine
        self.modes = ModeChanges()                       # its manual / fail-safe changes

    @property
    def files(self) -> dict[str, Path]:
        return {'trace': self.outputs.trace.path, 'recording': self.outputs.recording.path}

    def on_message(self, raw: RawMessage) -> None:
        """One recorded message, as received."""
        self.outputs.recording.add(raw)
        topic = raw.topic.lstrip('/')
        if topic == 'parameter_events':
            self.states.add(raw)
            return
        if topic == MODE_TOPIC:
            self.modes.add(raw)
            return
        if topic not in TOPIC_PREFIX and topic not in LATE_TOPICS:
            return
        try:
            msg = _signal_message(raw)
        except (struct_error, UnicodeDecodeError, IndexError, ValueError):
            self.unreadable += 1                   # in run.mcap as received; not in the trace
            return
        self.joiner.add(msg)
        if topic == 'measurement':
            self.last_measurement = max(msg.stamp_ns, self.last_measurement or msg.stamp_ns)
            self.measurements.append((self.clock(), msg.stamp_ns))
            self.arrival_of.setdefault(msg.stamp_ns, raw.log_time_ns)

    def _on_row(self, names: Sequence[str], values: Sequence[float]) -> None:
        self.outputs.trace.add(names, values)
        stamp = self.joiner.last_row_ns
        assert stamp is not None                  # set before a row reaches the sink
        self.stamps.add(stamp)
        arrival = self.arrival_of.pop(stamp, None)
        if arrival is not None:
            self.arrivals.add(arrival)

    def advance(self) -> None:
        """Write the rows whose messages are all in (a later measurement arrived
        ``holdback`` ago)."""
        safe_before = self.clock() - self.holdback
        while self.measurements and self.measurements[0][0] <= safe_before:
            self.horizon = max(self.horizon, self.measurements.popleft()[1])
        self.joiner.advance(self.horizon)
        self.outputs.flush_now_and_then()

    def close(self, complete: bool = True) -> Trace:
        """Write the rows still held, close both files, return the table (with ``late``).

        A run that did not complete (``complete=False``) leaves out the row of its last
        measurement, and any row before it that the controller's answer did not reach: the
        recorder may receive the plant's tick k + 1 before the controller's answer to tick k
        (two publishers, two paths), so only rows known whole are written.
        """
        if self.trace is None:
            try:
                if complete:
                    self.joiner.flush()
                elif self.last_measurement is not None:
                    self.joiner.advance(self.last_measurement, answered=True)
            finally:
                self.trace = self.outputs.close()
            self.trace.late = self.joiner.late
        return self.trace
