"""The run's table: one row per plant tick, columns ``t``, ``y.*``, ``r.*``, ``u.*``, ``d.*``.

The same table comes from the in-process loop (``core/loop.py``) and from a
ROS run (the recorded ``measurement``, ``setpoint``, ``manipulated`` and
``disturbance`` messages joined on their stamps), so both write the same
``trace.csv`` and can be compared column by column.

Join rule for recorded messages (``from_messages``): the rows are the stamps of
the ``measurement`` messages; each other signal takes its latest message stamped
at or before the row's stamp (zero-order hold). In lockstep every answer is
stamped exactly ``t_k``, so the join is exact; an answer that is missing for a
row's stamp is counted (``TraceTable.late``) and its value carried from the
previous one, or NaN before the first.
"""
from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tank_control.core.interfaces import NS_PER_S

#: Topic → column prefix.
TOPIC_PREFIX = {'measurement': 'y', 'setpoint': 'r', 'manipulated': 'u', 'disturbance': 'd'}
PREFIX_ORDER = ('y', 'r', 'u', 'd')
#: The plant's ``disturbance`` input in a gated lockstep run (see ``Recorder.enable_gate``).
GATED_DISTURBANCE = 'disturbance_gated'


@dataclass(frozen=True)
class SignalMessage:
    """One received signal message: topic, stamp [ns], channels and values."""

    topic: str
    stamp_ns: int
    names: tuple[str, ...]
    values: tuple[float, ...]


@dataclass
class TraceTable:
    """Columns by name (``t`` first), all the same length; ``late`` counts per prefix
    how many rows had no message stamped exactly at the row's stamp."""

    columns: dict[str, np.ndarray]
    late: dict[str, int] = field(default_factory=dict)

    @property
    def t(self) -> np.ndarray:
        return self.columns['t']

    def __len__(self) -> int:
        return len(self.columns['t'])

    def channels(self, prefix: str) -> list[str]:
        """Channel names with a column ``<prefix>.<name>``, in column order."""
        return [name.split('.', 1)[1] for name in self.columns if name.startswith(prefix + '.')]

    def until(self, t_end: float) -> TraceTable:
        """Rows with ``t <= t_end`` (plus a 1 ns tolerance)."""
        keep = self.t <= t_end + 1e-9
        return TraceTable({k: v[keep] for k, v in self.columns.items()}, dict(self.late))

    def write_csv(self, path: str | Path) -> Path:
        """``trace.csv``: a header row of column names, values with full float64 precision."""
        path = Path(path)
        names = list(self.columns)
        data = np.column_stack([self.columns[n] for n in names]) if len(self) else np.empty((0, 0))
        with open(path, 'w', newline='') as handle:
            writer = csv.writer(handle)
            writer.writerow(names)
            for row in data:
                writer.writerow([repr(float(v)) for v in row])
        return path


def read_csv(path: str | Path) -> TraceTable:
    """Read a ``trace.csv`` written by ``TraceTable.write_csv``."""
    with open(path, newline='') as handle:
        reader = csv.reader(handle)
        names = next(reader)
        rows = [[float(v) for v in row] for row in reader]
    data = np.array(rows, dtype=float).reshape(len(rows), len(names))
    return TraceTable({name: data[:, i] for i, name in enumerate(names)})


def ordered(columns: Mapping[str, Sequence[float]]) -> TraceTable:
    """A table with columns sorted as ``t``, ``y.*``, ``r.*``, ``u.*``, ``d.*`` (others after)."""
    def rank(name: str) -> tuple[int, str]:
        if name == 't':
            return (0, '')
        prefix = name.split('.', 1)[0]
        return (1 + PREFIX_ORDER.index(prefix) if prefix in PREFIX_ORDER else 9, '')
    names = sorted(columns, key=rank)   # stable: keeps channel order within a prefix
    return TraceTable({n: np.asarray(columns[n], dtype=float) for n in names})


def from_core_trace(trace: object) -> TraceTable:
    """Adapt the in-process loop's result (a mapping of columns, or an object with
    ``columns``/``as_dict()``/``to_dict()``) to a ``TraceTable``."""
    for attr in ('as_dict', 'to_dict'):
        if hasattr(trace, attr):
            return ordered(getattr(trace, attr)())
    if hasattr(trace, 'columns') and isinstance(trace.columns, Mapping):
        return ordered(trace.columns)
    if isinstance(trace, Mapping):
        return ordered(trace)
    raise TypeError(f'cannot read a trace from {type(trace).__name__}')


def from_messages(messages: Iterable[SignalMessage], t0_ns: int = 0,
                  t_end_ns: int | None = None) -> TraceTable:
    """Join recorded signal messages into a table (see the module docstring).

    ``t0_ns`` is subtracted from the stamps (0 in sim/lockstep, where the sim
    clock starts at 0; the first measurement's stamp in wall mode); rows end at
    ``t_end_ns`` after ``t0_ns`` when given.
    """
    by_topic: dict[str, dict[int, dict[str, float]]] = {topic: {} for topic in TOPIC_PREFIX}
    channels: dict[str, list[str]] = {topic: [] for topic in TOPIC_PREFIX}
    for msg in messages:
        if msg.topic not in by_topic:
            continue
        slot = by_topic[msg.topic].setdefault(msg.stamp_ns, {})
        for name, value in zip(msg.names, msg.values):
            slot[name] = value        # a re-sent message of the same stamp is identical
            if name not in channels[msg.topic]:
                channels[msg.topic].append(name)
    stamps = sorted(s for s in by_topic['measurement'] if t_end_ns is None or s - t0_ns <= t_end_ns)
    columns: dict[str, np.ndarray] = {
        't': np.array([(s - t0_ns) / NS_PER_S for s in stamps], dtype=float)}
    late: dict[str, int] = {}
    for topic, prefix in TOPIC_PREFIX.items():
        held = _zoh_join(stamps, by_topic[topic], channels[topic])
        for name in channels[topic]:
            columns[f'{prefix}.{name}'] = held[name]
        if topic != 'measurement' and by_topic[topic]:
            late[prefix] = sum(1 for s in stamps if s not in by_topic[topic])
    table = ordered(columns)
    table.late = late
    return table


def _zoh_join(stamps: Sequence[int], messages: Mapping[int, Mapping[str, float]],
              names: Sequence[str]) -> dict[str, np.ndarray]:
    """Per channel: the latest value stamped at or before each row stamp (NaN before any)."""
    out = {name: np.full(len(stamps), math.nan) for name in names}
    order = sorted(messages)
    current: dict[str, float] = {}
    j = 0
    for i, stamp in enumerate(stamps):
        while j < len(order) and order[j] <= stamp:
            current.update(messages[order[j]])
            j += 1
        for name, value in current.items():
            out[name][i] = value
    return out


def max_abs_difference(a: TraceTable, b: TraceTable) -> tuple[float, str]:
    """Largest |a − b| over the columns both tables have (rows aligned by index), and where."""
    worst, where = 0.0, ''
    n = min(len(a), len(b))
    for name in a.columns:
        if name in b.columns:
            diff = np.abs(a.columns[name][:n] - b.columns[name][:n])
            if diff.size and (np.nanmax(diff) > worst or np.isnan(diff).any()):
                worst = math.inf if np.isnan(diff).any() else float(np.nanmax(diff))
                where = name
    return worst, where
