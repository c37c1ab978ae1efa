"""Clock modes and the lockstep bookkeeping shared by the nodes (docs/nodes.md, "Clock modes").

``StampedInbox`` collects the messages of one stamp from several topics and says when a
lockstep tick is complete (the plant: ``manipulated`` + ``disturbance``; a controller:
``measurement`` + ``setpoint`` + ``disturbance``); the reference's topics are ``Held``
streams there (lockstep: one message per change, docs/nodes.md "The reference");
``Answers`` keeps the messages a node published for a stamp, so a re-sent tick is answered
with the same messages; ``Scheduled`` holds wall-mode values that came ahead of their
instant. Times in integer nanoseconds.
"""
from __future__ import annotations

import heapq
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rclpy.clock import Clock

CLOCK_MODES = ('wall', 'sim', 'lockstep')


def steady_clock() -> Clock:
    """A monotonic wall clock for timers that must ignore ``use_sim_time``
    (pacing, re-sending, diagnostics). rclpy is imported here only: the rest of this module
    and the protocols (nodes/protocol/) are importable without it."""
    from rclpy.clock import Clock, ClockType
    return Clock(clock_type=ClockType.STEADY_TIME)


def is_sample_instant(t_ns: int, sample_time_ns: int) -> bool:
    """True if ``t_ns`` is a multiple of the sample time (integer arithmetic, no rounding)."""
    return sample_time_ns > 0 and t_ns % sample_time_ns == 0


def sim_sample_instant(now_ns: int, sample_time_ns: int) -> int:
    """The latest sample instant ``k * sample_time_ns <= now_ns`` (sim-clock sampling).

    A sim-time timer is due at ``k * sample_time_ns`` but runs when the executor
    gets to it, possibly several ``/clock`` messages later; after it runs, the
    next due instant lies beyond ``now_ns``. Stamping with the instant reached
    (rounding down) therefore gives strictly increasing stamps on the grid;
    rounding to the nearest instant would stamp a timer that runs more than half
    a period late with the next instant, which the following sample repeats.
    """
    return (now_ns // sample_time_ns) * sample_time_ns


@dataclass
class _Slot:
    arrived: set[str] = field(default_factory=set)
    values: dict[str, dict[str, float]] = field(default_factory=dict)


class Held:
    """A lockstep stream under zero-order hold: a message stamped ``s`` gives the values from
    ``s`` until the next message's stamp (the reference in lockstep publishes only changes,
    and a message at its horizon at least every ``lockstep.lookahead`` ticks).

    One writer publishes in stamp order and reliable delivery keeps that order, so holding a
    message stamped ``s`` means every change up to ``s`` is in: the values of ``t <= through``
    are known. A message stamped at or before one already held restarts the stream from its
    stamp (the reference re-sends what holds from the current tick on when the plant re-sends
    it; a restarted reference or plant starts again): what was held after it is dropped and
    comes again. Channels missing from a message keep their earlier values."""

    def __init__(self) -> None:
        self._base: dict[str, float] = {}                # the values before the first entry
        self._entries: list[tuple[int, dict[str, float]]] = []   # ascending stamps
        self._folded = -1                  # the latest stamp folded into ``_base``
        self.through = -1                  # values are known up to this stamp [ns]

    def put(self, t_ns: int, values: Mapping[str, float]) -> None:
        entries = self._entries
        while entries and entries[-1][0] > t_ns:
            entries.pop()
        if t_ns <= self._folded:           # restarts at or before what is folded
            entries.clear()
            self._base.update(values)
            self._folded = t_ns
        elif entries and entries[-1][0] == t_ns:
            entries[-1][1].update(values)
        else:
            entries.append((t_ns, dict(values)))
        self.through = t_ns

    def values(self, t_ns: int) -> dict[str, float]:
        """The values in force at ``t_ns`` (as far as received)."""
        out = dict(self._base)
        for stamp, values in self._entries:
            if stamp > t_ns:
                break
            out.update(values)
        return out

    def fold_until(self, t_ns: int) -> None:
        """Fold the messages stamped at or before ``t_ns`` into the base (the tick moved on)."""
        entries = self._entries
        n = 0
        while n < len(entries) and entries[n][0] <= t_ns:
            self._base.update(entries[n][1])
            self._folded = entries[n][0]
            n += 1
        if n:
            del entries[:n]

    def forget_from(self, t_ns: int) -> None:
        """A new plant session: what is known from ``t_ns`` on came from the old one."""
        if self.through >= t_ns:
            while self._entries and self._entries[-1][0] >= t_ns:
                self._entries.pop()
            self.through = self._folded = -1


class StampedInbox:
    """Messages of one lockstep tick, grouped by stamp and source topic.

    ``required`` maps each source (topic) to the channels it must deliver for a
    tick to be complete; a source with no channels only has to arrive (e.g. a
    disturbance message without channels). Values of one source may come in
    several messages of the same stamp (they are merged). A source in ``held``
    is a ``Held`` stream: it delivers for ``t`` once it is known through ``t``.
    """

    def __init__(self, required: Mapping[str, Sequence[str]],
                 held: Iterable[str] = ()) -> None:
        self.required = {src: tuple(chs) for src, chs in required.items()}
        self._slots: dict[int, _Slot] = {}
        self.held = {src: Held() for src in held}

    def put(self, source: str, t_ns: int, values: Mapping[str, float]) -> None:
        """Record that ``source`` sent ``values`` stamped ``t_ns``."""
        held = self.held.get(source)
        if held is not None:
            held.put(t_ns, values)
            return
        slot = self._slots.setdefault(t_ns, _Slot())
        slot.arrived.add(source)
        slot.values.setdefault(source, {}).update(values)

    def _delivered(self, source: str, t_ns: int) -> tuple[bool, dict[str, float]]:
        held = self.held.get(source)
        if held is not None:
            return held.through >= t_ns, held.values(t_ns)
        slot = self._slots.get(t_ns)
        if slot is None or source not in slot.arrived:
            return False, {}
        return True, slot.values.get(source, {})

    def complete(self, t_ns: int) -> bool:
        """True once every required source delivered all its channels for ``t_ns``."""
        for source, channels in self.required.items():
            arrived, got = self._delivered(source, t_ns)
            if not arrived or any(ch not in got for ch in channels):
                return False
        return True

    def missing(self, t_ns: int) -> list[str]:
        """``source`` or ``source.channel`` entries still missing for ``t_ns`` (diagnostics)."""
        out = []
        for source, channels in self.required.items():
            arrived, got = self._delivered(source, t_ns)
            if not arrived:
                out.append(source)
            else:
                out += [f'{source}.{ch}' for ch in channels if ch not in got]
        return out

    def values(self, t_ns: int, source: str) -> dict[str, float]:
        """Channel values ``source`` delivered for ``t_ns`` (empty if none; a held source:
        those in force at ``t_ns``)."""
        held = self.held.get(source)
        if held is not None:
            return held.values(t_ns)
        slot = self._slots.get(t_ns)
        return dict(slot.values.get(source, {})) if slot else {}

    def drop_before(self, t_ns: int) -> None:
        """Forget every stamp earlier than ``t_ns`` (late duplicates of past ticks); held
        streams keep the values in force at ``t_ns``."""
        for stamp in [s for s in self._slots if s < t_ns]:
            del self._slots[stamp]
        for held in self.held.values():
            held.fold_until(t_ns)

    def drop_from(self, t_ns: int) -> None:
        """Forget every stamp at or after ``t_ns`` (a restarted plant's old session)."""
        for stamp in [s for s in self._slots if s >= t_ns]:
            del self._slots[stamp]
        for held in self.held.values():
            held.forget_from(t_ns)

    def stamps(self) -> Iterable[int]:
        return sorted(self._slots)


class Scheduled:
    """wall: input values that came ahead of their instant (the reference publishes each
    instant ``wall.lead`` early, stamped with it), held until a sample or step at or after
    their stamp takes them, in stamp order. Stamps in integer ns."""

    def __init__(self) -> None:
        self._pending: list[tuple[int, int, dict[str, float]]] = []   # heap: stamp, arrival
        self._arrivals = 0

    def put(self, t_ns: int, values: Mapping[str, float]) -> None:
        self._arrivals += 1
        heapq.heappush(self._pending, (t_ns, self._arrivals, dict(values)))

    def release(self, t_ns: int, into: dict[str, float]) -> None:
        """Move every value stamped at or before ``t_ns`` into ``into`` (later stamps win)."""
        while self._pending and self._pending[0][0] <= t_ns:
            into.update(heapq.heappop(self._pending)[2])

    def clear(self) -> None:
        self._pending.clear()

    def __len__(self) -> int:
        return len(self._pending)


class Answers:
    """Idempotent lockstep answers: the messages last published for a stamp.

    ``get(t_ns)`` returns the cached messages when ``t_ns`` was already
    answered (re-publish them, do not recompute), else ``None``.
    """

    def __init__(self) -> None:
        self.stamp: int | None = None
        self.messages: tuple = ()

    def get(self, t_ns: int) -> tuple | None:
        return self.messages if self.stamp == t_ns else None

    def remember(self, t_ns: int, *messages: object) -> tuple:
        self.stamp = t_ns
        self.messages = tuple(messages)
        return self.messages
