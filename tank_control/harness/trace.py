"""A ROS run's table (``core/trace.py``) from the recorded signal messages.

The ``measurement``, ``setpoint``, ``manipulated`` and ``disturbance`` messages are joined
on their stamps into the table the in-process loop writes. Join rule for recorded messages (``from_messages``): the rows are the stamps of
the ``measurement`` messages; each other signal takes its latest message stamped
at or before the row's stamp (zero-order hold). In lockstep every answer is
stamped exactly ``t_k``, so the join is exact; an answer that is missing for a
row's stamp is counted (``Trace.late``) and its value carried from the
previous one, or NaN before the first.
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
                  t_end_ns: int | None = None) -> Trace:
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
    table = Trace.ordered(columns)
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
