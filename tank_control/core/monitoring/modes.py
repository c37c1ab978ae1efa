"""A controller's mode changes over a run, for the manual and fail-safe times of its loops.

Both the in-process loop (core/loop.py ``modes``) and controller_node (``~/loop_mode``,
nodes/loop_performance.py) log, at each controller sample whose flags differ from the last
one's, ``[t, manual, fail_safe]``: the loop time [s] and whether the controller was in manual
mode and whether its output was held or fail-safe (a refused measurement, a controller fault).
A run's ``loop_performance`` turns the log into per-sample flags (:func:`flags_at`).
docs/monitoring.md."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class ModeLog:
    """The changes of (manual, fail_safe), sample by sample; the first sample is one."""

    def __init__(self) -> None:
        self.changes: list[list] = []          # [t [s], manual, fail_safe]
        self._last: tuple[bool, bool] | None = None

    def add(self, t: float, manual: bool, fail_safe: bool) -> list | None:
        """One controller sample; the change logged, or None when the flags are unchanged."""
        flags = (bool(manual), bool(fail_safe))
        if flags == self._last:
            return None
        self._last = flags
        change = [float(t), *flags]
        self.changes.append(change)
        return change


def flags_at(changes: Sequence[Sequence], t: np.ndarray, tolerance: float = 1e-6
             ) -> tuple[np.ndarray, np.ndarray] | None:
    """Per-sample (manual, fail_safe) flags at times ``t`` [s] from a mode log (a change
    applies from its own time on, to within ``tolerance`` [s]; before the first: neither);
    None for an empty or unreadable log (not known)."""
    try:
        rows = sorted((float(c[0]), bool(c[1]), bool(c[2])) for c in changes)
    except (TypeError, ValueError, IndexError):
        return None
    if not rows or not all(np.isfinite(r[0]) for r in rows):
        return None
    times = np.array([r[0] for r in rows])
    where = np.searchsorted(times, np.asarray(t, dtype=float) + tolerance, side='right') - 1
    manual = np.array([r[1] for r in rows])[np.maximum(where, 0)] & (where >= 0)
    fail_safe = np.array([r[2] for r in rows])[np.maximum(where, 0)] & (where >= 0)
    return manual, fail_safe
