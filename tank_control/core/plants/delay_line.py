"""Exact transport delays, pure dead time e^(−L·s) ([Viteckova] eq. 1, [DeadTimeNotes] eq. 6.14, [Michalski2021] §1).

``DelayLine`` delays a zero-order-hold signal exactly (stored as switch instants, returned as
constant pieces a plant integrates in closed form); ``HermiteDelayLine`` delays a continuous
signal known on an integration grid with its slopes (cubic Hermite between grid points). Both
keep ``max_delay`` seconds of history, so the delay can change at run time: y(t) = x(t − L(t))
(docs/plants.md). Switch times in integer ns; delays and interval lengths in s.
"""
from __future__ import annotations

import bisect
import math

from tank_control.core.interfaces import NS_PER_S, to_ns

_PRUNE_BATCH = 64
"""Stale entries are dropped in batches of this many (amortised list deletion)."""

_SNAP = 1e-12
"""Delayed switches closer than this [s] to a piece boundary are put on it, so
rounding of relative times never creates slivers of ~1e-16 s."""

Segment = tuple[float, float]
"""(duration [s], value) of one constant piece of a delayed ZOH signal."""


def _check_delay(delay: float, max_delay: float) -> None:
    if not (math.isfinite(delay) and 0.0 <= delay <= max_delay):
        raise ValueError(f'delay: {delay!r} outside the stored history; allowed [0, {max_delay:g}]')


class DelayLine:
    """Exact delay of a zero-order-hold signal stored as breakpoints.

    ``push(t_ns, value)`` records that the input holds ``value`` from ``t_ns``
    on; before the first breakpoint the input is ``initial`` (the line is
    pre-filled, i.e. the process was at rest before t = 0).
    ``segments(t0_ns, dt, delay)`` returns the delayed input
    x(t − delay) on [t0, t0 + dt) as consecutive ``(duration, value)`` pieces
    whose durations add up to ``dt``.
    """

    def __init__(self, max_delay: float, initial: float = 0.0) -> None:
        if not (math.isfinite(max_delay) and max_delay >= 0.0):
            raise ValueError(f'max_delay: {max_delay!r} must be finite and >= 0')
        self.max_delay = float(max_delay)
        self._keep_ns = to_ns(self.max_delay) + 2   # margin for the rounding to ns
        self.reset(initial)

    def reset(self, initial: float = 0.0) -> None:
        """Forget the history; the signal is ``initial`` at every past instant."""
        self._initial = float(initial)
        self._times: list[int] = []
        self._values: list[float] = []
        self._now_ns: int | None = None   # newest push instant
        self._delay = math.nan            # the last delay read [s] and to_ns of it
        self._delay_ns = 0

    def __len__(self) -> int:
        """Number of stored breakpoints."""
        return len(self._times)

    def push(self, t_ns: int, value: float) -> None:
        """The input holds ``value`` from ``t_ns`` on (times must not decrease)."""
        value = float(value)
        now_ns = self._now_ns
        if now_ns is not None and t_ns < now_ns:
            raise ValueError(f't_ns: {t_ns} is before the newest push {now_ns}')
        self._now_ns = int(t_ns)
        times, values = self._times, self._values
        if times:
            last = times[-1]
            if t_ns < last:
                raise ValueError(f't_ns: {t_ns} is before the last breakpoint {last}')
            if t_ns == last:
                values[-1] = value
                self._drop_repeat()
                return
            if value == values[-1]:
                if len(times) > _PRUNE_BATCH and times[_PRUNE_BATCH] <= t_ns - self._keep_ns:
                    self._prune(t_ns)   # (else there is nothing to drop yet)
                return
        elif value == self._initial:
            return
        times.append(int(t_ns))
        values.append(value)
        if len(times) > _PRUNE_BATCH and times[_PRUNE_BATCH] <= t_ns - self._keep_ns:
            self._prune(t_ns)       # (else there is nothing to drop yet)

    def _drop_repeat(self) -> None:
        previous = self._values[-2] if len(self._values) > 1 else self._initial
        if self._values[-1] == previous:
            self._times.pop()
            self._values.pop()

    def _prune(self, now_ns: int) -> None:
        """Keep every breakpoint newer than now − max_delay, and the one before
        (older ones are dropped in batches)."""
        cutoff = now_ns - self._keep_ns
        k = bisect.bisect_right(self._times, cutoff) - 1
        if k >= _PRUNE_BATCH:
            self._initial = self._values[k - 1]   # the value before the oldest kept breakpoint
            del self._times[:k]
            del self._values[:k]

    def value_at(self, t_ns: int) -> float:
        """The (undelayed) input at instant ``t_ns``."""
        k = bisect.bisect_right(self._times, t_ns) - 1
        return self._initial if k < 0 else self._values[k]

    def segments(self, t0_ns: int, dt: float, delay: float) -> list[Segment]:
        """Delayed input x(t − delay) on [t0, t0 + dt) as (duration, value) pieces.

        Delayed switch instants are computed relative to ``t0`` in seconds,
        ``seconds(t_switch − t0) + delay``, so they are exact to rounding and
        never snapped to a grid.
        """
        if not 0.0 <= delay <= self.max_delay:     # also NaN
            _check_delay(delay, self.max_delay)
        if not 0.0 <= dt < math.inf:                # dt < 0, NaN or infinite
            raise ValueError(f'dt: {dt!r} must be finite and >= 0')
        # Start from the last breakpoint that is certainly in force at t0 − delay
        # (a 2 ns margin absorbs the rounding of delay to nanoseconds) and walk
        # forward; delayed positions are exact relative times in seconds.
        if delay != self._delay:                    # to_ns(delay), kept for the next call
            self._delay, self._delay_ns = delay, to_ns(delay)
        read_ns = t0_ns - self._delay_ns
        if self._now_ns is not None and read_ns < self._now_ns - self._keep_ns:
            raise ValueError(f't0_ns: {t0_ns} minus the delay reads history older than max_delay')
        times, values = self._times, self._values
        k = bisect.bisect_right(times, read_ns - 2) - 1
        value = self._initial if k < 0 else values[k]
        pieces: list[Segment] = []
        start = 0.0
        snap = _SNAP
        end = dt - snap
        for i in range(k + 1, len(times)):          # k >= -1
            r = (times[i] - t0_ns) / NS_PER_S + delay
            if r >= end:
                break
            if r > start + snap:
                pieces.append((r - start, value))
                start = r
            value = values[i]
        if dt > start or not pieces:
            pieces.append((dt - start, value))
        return pieces


class HermiteDelayLine:
    """Delay of a continuous signal known on a (possibly non-uniform) grid.

    The grid starts at ``t0`` with ``initial`` and grows with ``append``; each
    interval carries the slopes at its two ends (one-sided, so kinks where the
    inputs switch are represented exactly). Before ``t0`` the signal is
    ``initial`` (pre-filled history).
    """

    def __init__(self, max_delay: float, initial: float = 0.0, t0: float = 0.0) -> None:
        if not (math.isfinite(max_delay) and max_delay >= 0.0):
            raise ValueError(f'max_delay: {max_delay!r} must be finite and >= 0')
        self.max_delay = float(max_delay)
        self.reset(initial, t0)

    def reset(self, initial: float = 0.0, t0: float = 0.0) -> None:
        """Forget the history: the signal is ``initial`` up to ``t0``."""
        self._initial = float(initial)
        self._t = [float(t0)]
        self._y = [float(initial)]
        self._slope_start: list[float] = []   # slope at the left end of interval i
        self._slope_end: list[float] = []     # slope at the right end of interval i

    def __len__(self) -> int:
        """Number of stored grid points."""
        return len(self._t)

    @property
    def last_time(self) -> float:
        """The newest grid instant [s]."""
        return self._t[-1]

    def append(self, t: float, y: float, slope_start: float, slope_end: float) -> None:
        """Add the interval from the newest grid point to ``(t, y)``.

        ``slope_start`` is the derivative at the newest point and ``slope_end``
        the derivative at ``t``, both evaluated with the inputs of this interval.
        """
        if not t > self._t[-1]:
            raise ValueError(f't: {t!r} is not after the newest grid point {self._t[-1]!r}')
        self.extend(float(t), float(y), float(slope_start), float(slope_end))

    def extend(self, t: float, y: float, slope_start: float, slope_end: float) -> None:
        """:meth:`append` of Python floats if ``t`` is after the newest grid point, else
        nothing."""
        grid = self._t
        if not t > grid[-1]:
            return
        grid.append(t)
        self._y.append(y)
        self._slope_start.append(slope_start)
        self._slope_end.append(slope_end)
        if len(grid) > _PRUNE_BATCH and grid[_PRUNE_BATCH] <= t - self.max_delay:
            self._prune(t)          # (else there is nothing to drop yet)

    def _prune(self, now: float) -> None:
        cutoff = now - self.max_delay
        k = bisect.bisect_right(self._t, cutoff) - 1
        if k >= _PRUNE_BATCH:
            # The first grid point is now after the pre-filled part: the oldest
            # retained value stands for everything before it.
            self._initial = self._y[k]
            del self._t[:k]
            del self._y[:k]
            del self._slope_start[:k]
            del self._slope_end[:k]

    def value_at(self, t: float) -> float:
        """The signal at instant ``t`` [s] (``t`` at most the newest grid instant)."""
        grid, ys = self._t, self._y
        if t <= grid[0]:
            return self._initial if t < grid[0] else ys[0]
        if t >= grid[-1]:
            if t - grid[-1] > 1e-9 * max(1.0, abs(t)):
                raise ValueError(f't: {t!r} is after the newest grid point {grid[-1]!r}')
            return ys[-1]
        i = bisect.bisect_right(grid, t) - 1
        t_a, t_b = grid[i], grid[i + 1]
        h = t_b - t_a
        s = (t - t_a) / h
        if s == 0.0:
            return ys[i]
        y_a, y_b = ys[i], ys[i + 1]
        m_a, m_b = self._slope_start[i] * h, self._slope_end[i] * h
        s2, s3 = s * s, s * s * s
        return ((2 * s3 - 3 * s2 + 1) * y_a + (s3 - 2 * s2 + s) * m_a
                + (-2 * s3 + 3 * s2) * y_b + (s3 - s2) * m_b)

    def delayed(self, now: float, delay: float) -> float:
        """The signal ``delay`` seconds before ``now``."""
        if not 0.0 <= delay <= self.max_delay:     # also NaN
            _check_delay(delay, self.max_delay)
        return self.value_at(now - delay)
