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


#: The reference schedules of the reference tests (flat parameters, as in a params file): a
#: setpoint step 1 → 2 at 0.3 s within [0, 10], a disturbance ramp 0 → −0.5 from 0.5 s at 1 /s.
REFERENCE = {
    'setpoint.channels': ['y'],
    'setpoint.y.times': [0.0, 0.3], 'setpoint.y.values': [1.0, 2.0],
    'setpoint.y.min': 0.0, 'setpoint.y.max': 10.0,
    'disturbance.channels': ['v'],
    'disturbance.v.times': [0.0, 0.5], 'disturbance.v.values': [0.0, -0.5],
    'disturbance.v.ramp_rate': 1.0,
}
