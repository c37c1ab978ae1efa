"""A ROS run's table (``core/trace.py``) from the recorded signal messages.

The ``measurement``, ``setpoint``, ``manipulated`` and ``disturbance`` messages are joined on
their stamps into the table the in-process loop writes: row k holds what acts over
``[t_k, t_k+1)`` (zero-order hold). The join rule and the late-sample rule (``Trace.late``):
docs/harness.md ("trace.csv", "Late samples"). Stamps in integer ns. ``TraceJoiner`` joins
the messages as they arrive, row by row, with the same result (docs/harness.md, "Interrupted
and failed runs").
"""
from __future__ import annotations

import heapq
import math
from collections import OrderedDict, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from tank_control.core.interfaces import NS_PER_S
from tank_control.core.trace import PREFIX_ORDER, Trace

#: Topic → column prefix.
TOPIC_PREFIX = {'measurement': 'y', 'setpoint': 'r', 'manipulated': 'u', 'disturbance': 'd'}
#: Reports of answers that came after their consumer had used the tick (``~/late_inputs``).
LATE_TOPICS = ('plant/late_inputs', 'controller/late_inputs')
#: The plant's ``disturbance`` input in a gated lockstep run (see ``Recorder.enable_gate``).
GATED_DISTURBANCE = 'disturbance_gated'

_ANSWERS = {'setpoint': 'r', 'manipulated': 'u', 'disturbance': 'd'}
#: Answer signals published under zero-order hold in lockstep (the reference, one message per
#: change and ``lockstep.lookahead`` ticks ahead: docs/nodes.md "The reference").
HELD_IN_LOCKSTEP = ('r', 'd')
_NEVER = math.inf
#: Applied messages remembered per topic to recognise a late repetition of one.
_RECENT = 256


@dataclass(frozen=True)
class SignalMessage:
    """One received signal message: topic, stamp [ns], channels and values."""

    topic: str
    stamp_ns: int
    names: tuple[str, ...]
    values: tuple[float, ...]


RowSink = Callable[[Sequence[str], Sequence[float]], None]
"""Receives each finished row: column names (``t`` first) and values."""


class _Signal:
    """Messages of one topic not yet applied to a row, and the values held so far."""

    def __init__(self) -> None:
        self.pending: dict[int, dict[str, float]] = {}
        self.order: list[int] = []             # heap of pending stamps
        self.held: dict[str, float] = {}        # zero-order hold: the latest applied values
        self.channels: list[str] = []
        self.seen = False
        self.recent: OrderedDict[int, dict[str, float]] = OrderedDict()

    def repeats(self, stamp: int, names: Sequence[str], values: Sequence[float]) -> bool:
        """Is this a repetition of a message already applied?"""
        applied = self.recent.get(stamp)
        return applied is not None and all(applied.get(n) == v for n, v in zip(names, values))

    def add(self, stamp: int, names: Sequence[str], values: Sequence[float]) -> None:
        self.seen = True
        slot = self.pending.get(stamp)
        if slot is None:
            slot = self.pending[stamp] = {}
            heapq.heappush(self.order, stamp)
        for name, value in zip(names, values):
            slot[name] = value        # a re-sent message of the same stamp is identical
            if name not in self.channels:
                self.channels.append(name)

    def apply_before(self, end: int) -> None:
        while self.order and self.order[0] < end:
            stamp = heapq.heappop(self.order)
            values = self.pending.pop(stamp)
            self.held.update(values)
            self.recent[stamp] = values
            if len(self.recent) > _RECENT:
                self.recent.popitem(last=False)


class _Due:
    """Late counting of one answer signal (module docstring): due instants waiting for their
    answer window to close, and the answer and report stamps not yet looked at."""

    def __init__(self, period: int, held: bool = False) -> None:
        self.period = period
        self.held = held                          # answered by any message stamped at or after
        self.waiting: deque[int] = deque()        # due instants, plant time [ns]
        self.answers: list[int] = []              # heaps of absolute stamps
        self.reported: list[int] = []
        self.late = 0

    def settle(self, t0: int, horizon: float) -> None:
        """Count every waiting instant whose window ``[t_e, t_e + period)`` ends by ``horizon``."""
        while self.waiting and t0 + self.waiting[0] + self.period <= horizon:
            start = t0 + self.waiting.popleft()
            end = start + self.period
            answered = _pop_before(self.answers, start, _NEVER if self.held else end)
            reported = _pop_before(self.reported, start, end)
            self.late += (not answered) or reported


def _pop_before(heap: list[int], start: int, end: float) -> bool:
    """Drop stamps before ``start`` (windows already counted); is one in ``[start, end)``?"""
    while heap and heap[0] < start:
        heapq.heappop(heap)
    return bool(heap) and heap[0] < end


class TraceJoiner:
    """The join of the module docstring, row by row as messages arrive.

    ``origin`` gives ``t0`` [ns] (the plant's time origin), asked once, when the first row
    is finished; ``t_end_ns`` [ns after t0] drops later rows; ``tick_ns``, ``due_ns``, ``held``
    as for ``from_messages``. Each finished row goes to ``sink``.
    """

    def __init__(self, sink: RowSink, origin: Callable[[], int] = lambda: 0,
                 t_end_ns: int | None = None, tick_ns: int | None = None,
                 due_ns: Mapping[str, int] | None = None, held: Iterable[str] = ()) -> None:
        self.sink = sink
        self.origin = origin
        self.t_end_ns = t_end_ns
        self.tick_ns = tick_ns
        self.due_ns = dict(due_ns or {})
        self.t0: int | None = None
        self.signals = {topic: _Signal() for topic in TOPIC_PREFIX}
        self.rows: list[int] = []                  # heap of measurement stamps not yet written
        self.row_stamps: set[int] = set()
        self.due = {prefix: _Due(self.due_ns.get(prefix) or tick_ns or 1, prefix in held)
                    for prefix in _ANSWERS.values()}
        self.inputs: set[str] = set()              # channels of ``manipulated`` seen
        self.latest_input: int | None = None       # the latest ``manipulated`` stamp [ns]
        self.written = 0
        self.written_until = -_NEVER               # rows end before this: every row is written
        self.after_written = 0
        self.last_row_ns: int | None = None
        self._channel_lists = [self.signals[_TOPIC_OF[prefix]].channels for prefix in PREFIX_ORDER]
        self._columns_key: tuple[int, ...] | None = None
        self._columns_cache: tuple[tuple[str, ...], list[tuple[_Signal, tuple[str, ...]]]] = (
            ('t',), [])

    # -- input -------------------------------------------------------------------------------
    def add(self, msg: SignalMessage) -> None:
        """A signal message (``TOPIC_PREFIX``) or a late report (``LATE_TOPICS``)."""
        if msg.topic in LATE_TOPICS:
            self._add_report(msg)
            return
        signal = self.signals.get(msg.topic)
        if signal is None:
            return
        stamp = msg.stamp_ns
        if msg.topic == 'manipulated':
            self.inputs.update(msg.names)
            if self.latest_input is None or stamp > self.latest_input:
                self.latest_input = stamp
        if stamp < self.written_until:
            signal.seen = True
            if not signal.repeats(stamp, msg.names, msg.values):
                self.after_written += 1
            return
        signal.add(stamp, msg.names, msg.values)
        prefix = _ANSWERS.get(msg.topic)
        if prefix is not None:
            heapq.heappush(self.due[prefix].answers, stamp)
        elif stamp not in self.row_stamps and self._within(stamp):
            self.row_stamps.add(stamp)
            heapq.heappush(self.rows, stamp)

    def _add_report(self, msg: SignalMessage) -> None:
        if msg.topic.startswith('controller'):
            prefix = 'r'
        else:
            prefix = 'u' if set(msg.names) <= self.inputs else 'd'
        heapq.heappush(self.due[prefix].reported, msg.stamp_ns)

    def _within(self, stamp: int) -> bool:
        if self.t_end_ns is None:
            return True
        t0 = self.t0 if self.t0 is not None else None
        # before the origin is known a row is kept; it is dropped when written if beyond
        return t0 is None or stamp - t0 <= self.t_end_ns

    # -- output ------------------------------------------------------------------------------
    def advance(self, horizon: float, answered: bool = False) -> None:
        """Every message stamped before ``horizon`` [ns] is in: write the rows that end by then.

        ``answered``: write only rows the controller answered (a ``manipulated`` message
        stamped at or after the row came; one publisher's messages arrive in order) — for a
        run that stopped before the answers to its last measurements came."""
        while self.rows:
            stamp = self.rows[0]
            if answered and self.latest_input is not None and stamp > self.latest_input:
                break
            after = self._next_row_after(stamp)
            end = stamp + self.tick_ns if self.tick_ns else stamp + 1
            if after is not None:
                end = min(end, after)
            if end > horizon:
                break
            heapq.heappop(self.rows)
            self.row_stamps.discard(stamp)
            self._write_row(stamp, end)
        if self.t0 is not None:
            for due in self.due.values():
                due.settle(self.t0, horizon)

    def _next_row_after(self, stamp: int) -> int | None:
        rows = self.rows
        if len(rows) < 2:
            return None
        # the heap's second-smallest element is one of its two children of the root
        return min(rows[1:3])

    def _write_row(self, stamp: int, end: int) -> None:
        if self.t0 is None:
            self.t0 = self.origin()
        t_rel = stamp - self.t0
        if self.t_end_ns is not None and t_rel > self.t_end_ns:
            return
        for signal in self.signals.values():
            signal.apply_before(end)
        self.written_until = max(self.written_until, end)
        values = [t_rel / NS_PER_S]
        columns = self._columns()
        for signal, channels in columns[1]:
            held = signal.held
            values.extend([held.get(name, math.nan) for name in channels])
        names = columns[0]
        for prefix, due in self.due.items():
            if t_rel % due.period == 0:
                due.waiting.append(t_rel)
        self.written += 1
        self.last_row_ns = stamp                   # before the sink, which may read it
        self.sink(names, values)

    def _columns(self) -> tuple[tuple[str, ...], list[tuple[_Signal, tuple[str, ...]]]]:
        """The row's column names (``t``, then each prefix's channels in order of arrival) and
        (signal, channels) in the same order; rebuilt only when a signal gained a channel
        (channels are only ever appended), not per row."""
        key = tuple(map(len, self._channel_lists))
        if key != self._columns_key:
            names = ['t']
            parts = []
            for prefix in PREFIX_ORDER:
                signal = self.signals[_TOPIC_OF[prefix]]
                channels = tuple(signal.channels)
                names += [f'{prefix}.{name}' for name in channels]
                parts.append((signal, channels))
            self._columns_key, self._columns_cache = key, (tuple(names), parts)
        return self._columns_cache

    def flush(self) -> None:
        """Write every remaining row and count every remaining due instant (end of the run)."""
        self.advance(_NEVER)
        if self.t0 is None:
            self.t0 = self.origin() if self.written else 0
        for due in self.due.values():
            due.settle(self.t0, _NEVER)

    @property
    def late(self) -> dict[str, int]:
        """Late answers per prefix, for the answer signals that had any message."""
        return {prefix: self.due[prefix].late for topic, prefix in _ANSWERS.items()
                if self.signals[topic].seen}


_TOPIC_OF = {prefix: topic for topic, prefix in TOPIC_PREFIX.items()}


def from_messages(messages: Iterable[SignalMessage], t0_ns: int = 0,
                  t_end_ns: int | None = None, tick_ns: int | None = None,
                  due_ns: Mapping[str, int] | None = None,
                  late_stamps: Mapping[str, Iterable[int]] | None = None,
                  held: Iterable[str] = ()) -> Trace:
    """Join recorded signal messages into a table (join rule: docs/harness.md, "trace.csv").

    ``t0_ns`` is subtracted from the stamps (the plant's time origin: 0 in
    sim/lockstep, the wall time of its tick 0 in wall mode); rows end at
    ``t_end_ns`` after ``t0_ns`` when given. ``tick_ns`` is the plant tick
    (without it a row takes messages stamped at or before its own stamp and
    answers are due at every row, stamped exactly); ``due_ns`` the period of
    each signal prefix (default: the tick) and ``late_stamps`` the stamps its
    consumer reported late, per prefix. A prefix in ``held`` is published under
    zero-order hold (``HELD_IN_LOCKSTEP``): a due instant is answered by any message
    stamped at or after it.
    """
    rows: list[tuple[Sequence[str], Sequence[float]]] = []
    joiner = TraceJoiner(lambda names, values: rows.append((names, values)), lambda: t0_ns,
                         t_end_ns, tick_ns, due_ns, held)
    joiner.t0 = t0_ns
    for msg in messages:
        joiner.add(msg)
    for prefix, stamps in (late_stamps or {}).items():
        for stamp in stamps:
            heapq.heappush(joiner.due[prefix].reported, stamp)
    joiner.flush()
    names = rows[-1][0] if rows else ['t']
    columns: dict[str, list[float]] = {name: [] for name in names}
    for row_names, values in rows:
        row = dict(zip(row_names, values))
        for name in names:
            columns[name].append(row.get(name, math.nan))
    table = Trace.ordered(columns)
    table.late = joiner.late
    return table
