"""Signal samples between the ROS thread and the web clients, without loss up to a bound.

Every message of a signal topic becomes one row ``(seq, topic, t, names, values)`` with a
global sequence number; a web client keeps a cursor (the last ``seq`` it was sent) and takes
every row after it in one batch (:meth:`SampleStore.since`). The store keeps the last
``capacity`` rows; a client so far behind that rows it had not taken were dropped is told how
many (``lost``). Times ``t`` in s of plant time (stamp − the plant's ``time_origin``), values
in the channel's units.
"""
from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Row:
    """One message of a signal topic."""

    seq: int
    topic: str
    t: float
    names: tuple[str, ...]
    values: tuple[float, ...]


@dataclass
class Batch:
    """The rows after a cursor: ``rows``, the cursor to use next, and how many rows after the
    old cursor were no longer held (dropped by the bound)."""

    rows: list[Row]
    cursor: int
    lost: int

    def as_message(self) -> dict[str, Any]:
        """The batch as a JSON-able message: per topic the times and, per channel, the values
        (``None`` where a message did not carry the channel or its value was not finite)."""
        topics: dict[str, dict[str, Any]] = {}
        for row in self.rows:
            entry = topics.setdefault(row.topic, {'t': [], 'ch': {}})
            n = len(entry['t'])
            entry['t'].append(row.t)
            for name, value in zip(row.names, row.values):
                column: list[float | None] | None = entry['ch'].get(name)
                if column is None:
                    column = [None] * n
                    entry['ch'][name] = column
                column.append(value if math.isfinite(value) else None)
            for column in entry['ch'].values():
                if len(column) == n:
                    column.append(None)
        return {'type': 'samples', 'first': self.rows[0].seq if self.rows else self.cursor + 1,
                'last': self.cursor, 'lost': self.lost, 'topics': topics}


@dataclass
class SampleStore:
    """Thread-safe bounded store of signal rows (``capacity`` rows, oldest dropped first)."""

    capacity: int
    _rows: deque[Row] = field(init=False)
    _seq: int = field(default=0, init=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, init=False)

    def __post_init__(self) -> None:
        if self.capacity < 1:
            raise ValueError(f'capacity: {self.capacity} is below the minimum 1')
        self._rows = deque(maxlen=self.capacity)

    def add(self, topic: str, t: float, names: Sequence[str], values: Sequence[float]) -> int:
        """Append one message; returns its sequence number."""
        with self._lock:
            self._seq += 1
            self._rows.append(Row(self._seq, topic, t, tuple(names), tuple(values)))
            return self._seq

    @property
    def last_seq(self) -> int:
        """Sequence number of the newest row (0 before the first)."""
        with self._lock:
            return self._seq

    def oldest_cursor(self) -> int:
        """The cursor that takes every row still held (a new client's start)."""
        with self._lock:
            return self._rows[0].seq - 1 if self._rows else self._seq

    def since(self, cursor: int, limit: int | None = None) -> Batch:
        """Rows with ``seq > cursor`` (at most ``limit``, oldest first)."""
        with self._lock:
            if not self._rows or cursor >= self._seq:
                return Batch([], min(cursor, self._seq), 0)
            oldest = self._rows[0].seq
            lost = max(0, oldest - cursor - 1)
            start = max(cursor + 1, oldest) - oldest        # index of the first row to take
            stop = len(self._rows) if limit is None else min(len(self._rows), start + limit)
            rows = [self._rows[i] for i in range(start, stop)]
        return Batch(rows, rows[-1].seq, lost)
