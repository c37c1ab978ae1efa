"""A ROS run's table (``core/trace.py``) from the recorded signal messages.

The ``measurement``, ``setpoint``, ``manipulated`` and ``disturbance`` messages are joined on
their stamps into the table the in-process loop writes: row k holds what acts over
``[t_k, t_k+1)`` (zero-order hold). The join rule and the late-sample rule (``Trace.late``):
docs/harness.md ("trace.csv", "Late samples"). Stamps in integer ns.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tank_control.core.interfaces import NS_PER_S
from tank_control.core.trace import Trace

#: Topic → column prefix.
TOPIC_PREFIX = {'measurement': 'y', 'setpoint': 'r', 'manipulated': 'u', 'disturbance': 'd'}
#: Reports of answers that came after their consumer had used the tick (``~/late_inputs``).
LATE_TOPICS = ('plant/late_inputs', 'controller/late_inputs')
#: The plant's ``disturbance`` input in a gated lockstep run (see ``Recorder.enable_gate``).
GATED_DISTURBANCE = 'disturbance_gated'


@dataclass(frozen=True)
class SignalMessage:
    """One received signal message: topic, stamp [ns], channels and values."""

    topic: str
    stamp_ns: int
    names: tuple[str, ...]
    values: tuple[float, ...]


def from_messages(messages: Iterable[SignalMessage], t0_ns: int = 0,
                  t_end_ns: int | None = None, tick_ns: int | None = None,
                  due_ns: Mapping[str, int] | None = None,
                  late_stamps: Mapping[str, Iterable[int]] | None = None) -> Trace:
    """Join recorded signal messages into a table (join rule: docs/harness.md, "trace.csv").

    ``t0_ns`` is subtracted from the stamps (the plant's time origin: 0 in
    sim/lockstep, the wall time of its tick 0 in wall mode); rows end at
    ``t_end_ns`` after ``t0_ns`` when given. ``tick_ns`` is the plant tick
    (without it a row takes messages stamped at or before its own stamp and
    answers are due at every row, stamped exactly); ``due_ns`` the period of
    each signal prefix (default: the tick) and ``late_stamps`` the stamps its
    consumer reported late, per prefix.
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
    if tick_ns:      # row k: [t_k, t_k+1), at most one tick (a lost row leaves a gap)
        ends = [min(a + tick_ns, b) for a, b in zip(stamps, [*stamps[1:], stamps[-1] + tick_ns])] \
            if stamps else []
    else:
        ends = [s + 1 for s in stamps]
    columns: dict[str, np.ndarray] = {
        't': np.array([(s - t0_ns) / NS_PER_S for s in stamps], dtype=float)}
    late: dict[str, int] = {}
    for topic, prefix in TOPIC_PREFIX.items():
        held = _zoh_join(stamps, ends, by_topic[topic], channels[topic])
        for name in channels[topic]:
            columns[f'{prefix}.{name}'] = held[name]
        if topic != 'measurement' and by_topic[topic]:
            period = (due_ns or {}).get(prefix) or tick_ns or 1
            reported = (late_stamps or {}).get(prefix, ())
            late[prefix] = _late_count([s - t0_ns for s in stamps],
                                       [s - t0_ns for s in by_topic[topic]],
                                       [s - t0_ns for s in reported], period)
    table = Trace.ordered(columns)
    table.late = late
    return table


def _late_count(rows: Sequence[int], answers: Sequence[int], reported: Iterable[int],
                period: int) -> int:
    """Due instants (rows on the ``period`` grid of plant time) with no answer stamped in
    ``[t_e, t_e + period)``, plus due instants whose answer was reported late."""
    if not rows:
        return 0
    due = [t for t in rows if t % period == 0]
    answered = {a // period * period for a in answers}
    reported_due = {r // period * period for r in reported} & set(due)
    missing = {t for t in due if t not in answered}
    return len(missing) + len(reported_due - missing)


def _zoh_join(stamps: Sequence[int], ends: Sequence[int],
              messages: Mapping[int, Mapping[str, float]],
              names: Sequence[str]) -> dict[str, np.ndarray]:
    """Per channel: the latest value stamped before each row's end (NaN before any)."""
    out = {name: np.full(len(stamps), math.nan) for name in names}
    order = sorted(messages)
    current: dict[str, float] = {}
    j = 0
    for i, end in enumerate(ends):
        while j < len(order) and order[j] < end:
            current.update(messages[order[j]])
            j += 1
        for name, value in current.items():
            out[name][i] = value
    return out
