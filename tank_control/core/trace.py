"""The run's table: one row per plant tick, columns ``t`` [s], ``y.*``, ``r.*``, ``u.*``, ``d.*``.

The in-process loop (``core/loop.py``) and a ROS run (recorded messages joined on their stamps,
``harness/trace.py``) produce the same table and write the same ``trace.csv``, so the two can be
compared column by column. ``late`` counts, per column prefix, the rows of a ROS run whose
message did not carry exactly the row's stamp (its value was carried over).
"""
from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

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
                writer.writerow([repr(float(v)) for v in row])
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
