"""The run's table: one row per plant tick, columns ``t`` [s], ``y.*``, ``r.*``, ``u.*``, ``d.*``.

The in-process loop (``core/loop.py``) and a ROS run (recorded messages joined on their stamps,
``harness/trace.py``) produce the same table and write the same ``trace.csv``, so the two can be
compared column by column. ``late`` counts, per column prefix, the rows of a ROS run whose
message did not carry exactly the row's stamp (its value was carried over). ``TraceWriter``
writes ``trace.csv`` row by row as a run produces it.
"""
from __future__ import annotations

import csv
import math
from array import array
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

PREFIX_ORDER = ('y', 'r', 'u', 'd')


@dataclass
class Trace:
    """Columns by name (``t`` first), all of one length."""

    columns: dict[str, np.ndarray] = field(default_factory=dict)
    late: dict[str, int] = field(default_factory=dict)

    @classmethod
    def from_rows(cls, names: Sequence[str], rows: Iterable[Sequence[float]]) -> Trace:
        if not isinstance(rows, np.ndarray):
            rows = list(rows)
        data = np.asarray(rows, dtype=float).reshape(-1, len(names))
        return cls({name: data[:, i].copy() for i, name in enumerate(names)})

    @classmethod
    def ordered(cls, columns: Mapping[str, Sequence[float]]) -> Trace:
        """A table with columns sorted as ``t``, ``y.*``, ``r.*``, ``u.*``, ``d.*`` (others
        after; channel order kept within a prefix)."""
        def rank(name: str) -> int:
            if name == 't':
                return 0
            prefix = name.split('.', 1)[0]
            return 1 + PREFIX_ORDER.index(prefix) if prefix in PREFIX_ORDER else 9
        return cls({n: np.asarray(columns[n], dtype=float) for n in sorted(columns, key=rank)})

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.columns)

    @property
    def t(self) -> np.ndarray:
        return self.columns['t']

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __len__(self) -> int:
        return len(self.columns['t']) if 't' in self.columns else 0

    def channels(self, prefix: str) -> list[str]:
        """Channel names with a column ``<prefix>.<name>``, in column order."""
        return [name.split('.', 1)[1] for name in self.columns if name.startswith(prefix + '.')]

    def until(self, t_end: float) -> Trace:
        """Rows with ``t <= t_end`` (plus a 1 ns tolerance)."""
        keep = self.t <= t_end + 1e-9
        return Trace({k: v[keep] for k, v in self.columns.items()}, dict(self.late))

    def write_csv(self, path: str | Path) -> Path:
        """``trace.csv``: a header row of column names, then one row per tick (full float64
        precision, so a file read back is bit-identical)."""
        path = Path(path)
        with path.open('w', newline='') as handle:
            writer = csv.writer(handle)
            writer.writerow(self.names)
            for row in zip(*self.columns.values()):
                writer.writerow(_csv_row(row))
        return path

    @classmethod
    def read_csv(cls, path: str | Path) -> Trace:
        """A table written by :meth:`write_csv`."""
        with Path(path).open(newline='') as handle:
            reader = csv.reader(handle)
            names = next(reader)
            return cls.from_rows(names, ([float(v) for v in row] for row in reader))

    def max_abs_difference(self, other: Trace, names: Iterable[str] | None = None
                           ) -> dict[str, float]:
        """Per common column (or ``names``): the largest absolute difference, rows aligned by
        index; ``inf`` if the lengths differ or a value is NaN in one table only."""
        out = {}
        for name in [n for n in (names or self.names) if n in other.columns]:
            a, b = self.columns[name], other.columns[name]
            if len(a) != len(b):
                out[name] = float('inf')
            elif not len(a):
                out[name] = 0.0
            else:
                diff = np.abs(a - b)
                both_nan = np.isnan(a) & np.isnan(b)
                diff[both_nan] = 0.0
                out[name] = float('inf') if np.isnan(diff).any() else float(diff.max())
        return out


#: Line end of ``csv.writer`` (``write_csv``), so both write the same bytes.
_EOL = '\r\n'


def _csv_row(values: Iterable[float]) -> list[str]:
    return [repr(float(v)) for v in values]


class TraceWriter:
    """``trace.csv`` written as the rows come, with the columns kept in memory for the
    metrics (8 bytes per value).

    Rows are buffered as text and written whole by ``flush`` (and every ``BUFFER_ROWS``
    rows), one ``write`` per batch, so the file always ends at the end of a row: a
    process killed between flushes leaves a valid table of the rows flushed so far.

    The header is the names of the first row. A row with a column not seen before (a channel
    whose first message came late) adds it, NaN in the earlier rows; ``close`` then rewrites
    the file with every column.
    """

    #: Rows buffered before they are written even without a ``flush``.
    BUFFER_ROWS = 4096

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._handle: IO[str] | None = self.path.open('w', newline='')
        self._pending: list[str] = []
        self._names: tuple[str, ...] | None = None
        self._columns: dict[str, array] = {}
        self._rows = 0
        self._rewrite = False

    def __len__(self) -> int:
        return self._rows

    def add(self, names: Sequence[str], values: Sequence[float]) -> None:
        """One row: ``values`` of the columns ``names`` (``t`` first)."""
        names = tuple(names)
        if self._names is None:
            self._names = names
            self._columns = {name: array('d') for name in names}
            self._pending.append(','.join(names) + _EOL)
        if names != self._names:
            self._add_columns(names)
            row = dict(zip(names, values))
            values = [row.get(name, math.nan) for name in self._names]
        for column, value in zip(self._columns.values(), values):
            column.append(value)
        if not self._rewrite:
            self._pending.append(','.join(_csv_row(values)) + _EOL)
            if len(self._pending) >= self.BUFFER_ROWS:
                self.flush()
        self._rows += 1

    def _add_columns(self, names: Sequence[str]) -> None:
        new = [name for name in names if name not in self._columns]
        if not new:
            return
        for name in new:
            self._columns[name] = array('d', [math.nan]) * self._rows
        order = Trace.ordered({name: () for name in self._columns}).names
        self._columns = {name: self._columns[name] for name in order}
        self._names = tuple(order)
        self._rewrite = True

    def flush(self) -> None:
        """Write the buffered rows to the file (whole rows, one write)."""
        if self._handle is None or not self._pending:
            return
        self._handle.write(''.join(self._pending))
        self._pending.clear()
        self._handle.flush()

    def trace(self) -> Trace:
        """The rows so far as a table (a copy)."""
        return Trace({name: np.array(column, dtype=float) for name, column in self._columns.items()})

    def close(self) -> Trace:
        """Finish the file (rewritten if columns were added) and return the table."""
        if self._handle is not None:
            try:
                self.flush()
            finally:
                self._handle.close()
                self._handle = None
        table = Trace({name: np.frombuffer(column, dtype=float)    # no copy: no more rows
                       for name, column in self._columns.items()} or {'t': np.empty(0)})
        if self._names is None:
            self.path.write_text('t\n')                   # no row: a header with the time column
        elif self._rewrite:
            table.write_csv(self.path)
        return table
