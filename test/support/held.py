"""The reference's lockstep topics under zero-order hold (docs/nodes.md, "The reference"),
read back per tick: a message stamped s holds from s until the next message's stamp."""
from __future__ import annotations

import bisect
from collections.abc import Iterable, Mapping
from typing import TypeVar

#: Topics the reference publishes once per change (and ``lockstep.lookahead`` ahead) in lockstep.
HELD_TOPICS = ('setpoint', 'disturbance')

T = TypeVar('T')


def per_tick(by_stamp: Mapping[int, T], ticks: Iterable[int]) -> dict[int, T]:
    """The entry in force at each tick of ``ticks`` [ns] (the latest stamped at or before
    it), for the ticks some message stamped at or after covers; other ticks are left out."""
    stamps = sorted(by_stamp)
    out: dict[int, T] = {}
    for tick in ticks:
        i = bisect.bisect_right(stamps, tick)
        if i and stamps[-1] >= tick:
            out[tick] = by_stamp[stamps[i - 1]]
    return out
