"""Input messages stamped in the future, and messages too large to take (no rclpy here).

A consumer that takes only messages newer than the one it holds (docs/nodes.md, "Time base")
would be frozen by one message stamped far ahead: every genuine one after it is "older". So each
consumer first asks ``FutureStamps.admit`` whether a message's stamp is at most its tolerance
ahead of its own notion of now (wall: its clock; sim: its ``/clock`` time; lockstep: the current
tick); a message further ahead is refused (counted in ``refused``, reported once through
``take_report``) and the stream goes on with the valid messages.

A refused stream does not stay refused: when every message of one stream has been refused for
``RECOVER_S`` of wall time (monotonic) and at least ``RECOVER_MESSAGES`` of them came — a genuine
clock step (a host clock stepped back, the plant restarted with a new time origin on a host whose
clock is ahead), not one stray message between valid ones — the guard takes the stream's lead as
a clock offset and admits it from then on. So a stream whose messages come every ``p`` seconds is
taken again at most ``max(RECOVER_S + p, (RECOVER_MESSAGES - 1)·p)`` after its first refused
message. Times in integer nanoseconds.
"""
from __future__ import annotations

from dataclasses import dataclass, field

#: default tolerance ``max_future_stamp``: this many sample times of the consuming node
FUTURE_STAMP_SAMPLES = 5
#: lockstep: messages may run this many ticks ahead of the consumer's current tick (the
#: reference's ``lockstep.lookahead`` <= 8, plus the tick in flight)
LOCKSTEP_AHEAD_TICKS = 9
#: a stream refused without a break for this long [s of wall time] ...
RECOVER_S = 1.0
#: ... and for at least this many messages is a clock step: taken with its offset from then on
RECOVER_MESSAGES = 3
#: the most channel names a signal message may carry (a larger one is refused whole, counted)
MAX_NAMES = 256

_NS_PER_S = 1_000_000_000
#: wall: a plant (plant_node, opcua_bridge_node) announces its time origin this long ahead of
#: its clock, rounded up to whole periods [s]
ORIGIN_NOTICE_S = 0.2


def origin_refusal(origin_ns: int, held_ns: int | None, now_ns: int, tolerance_ns: int,
                   ts_ns: int) -> str | None:
    """Why a wall-mode consumer holding the time origin ``held_ns`` refuses a new
    ``time_origin`` ``origin_ns`` (None: take it): one further ahead of its clock ``now_ns``
    than a plant announces it (``ORIGIN_NOTICE_S`` + a period ``ts_ns``), its stamp tolerance
    and a second — it would stop the loop until real time reaches it. The first origin is
    always taken (nothing to go on with); a genuine one of a plant on a host whose clock is
    further ahead is taken by the controller once its measurements come on that time base
    (nodes/protocol/controller.WallTimerClock), by the reference when it is restarted."""
    if held_ns is None or origin_ns == held_ns:
        return None
    limit = round(ORIGIN_NOTICE_S * _NS_PER_S) + ts_ns + tolerance_ns + _NS_PER_S
    lead = origin_ns - now_ns
    if lead <= limit:
        return None
    return (f'time_origin {lead / _NS_PER_S:.6g} s ahead of this node\'s clock refused (a plant '
            f'announces it at most {limit / _NS_PER_S:g} s ahead): the loop goes on with the '
            'origin held')


def future_tolerance_ns(max_future_stamp: float | None, sample_time: float,
                        lockstep: bool = False) -> int:
    """The tolerance [ns] of a node with ``sample_time`` [s]: ``max_future_stamp`` [s] (0 or
    None: ``FUTURE_STAMP_SAMPLES`` sample times); in lockstep at least
    ``LOCKSTEP_AHEAD_TICKS`` sample times (the reference publishes ahead)."""
    ts_ns = round(sample_time * _NS_PER_S)
    given = float(max_future_stamp or 0.0)
    tol = round(given * _NS_PER_S) if given > 0 else FUTURE_STAMP_SAMPLES * ts_ns
    if lockstep:
        tol = max(tol, LOCKSTEP_AHEAD_TICKS * ts_ns)
    return tol


@dataclass
class _Stream:
    offset_ns: int = 0                 # the lead taken as a clock offset (a recovered step)
    refused_since: int | None = None   # wall time of the first refusal of the current run
    refused_run: int = 0               # messages refused in the current run


@dataclass
class FutureStamps:
    """Admits a stream's messages stamped at most ``tolerance_ns`` ahead of now (per stream).

    ``recover_ns``/``recover_messages``: a run of refusals this long (wall time) and this
    many messages is taken for a clock step (module docstring). ``refused`` counts refused
    messages; ``recovered`` the clock steps taken; ``returned`` the streams taken back on this
    node's clock after a step (``back_on_clock``)."""

    tolerance_ns: int
    recover_ns: int = int(RECOVER_S * _NS_PER_S)
    recover_messages: int = RECOVER_MESSAGES
    refused: int = 0
    recovered: int = 0
    returned: int = 0
    _streams: dict[str, _Stream] = field(default_factory=dict)
    _reports: list[str] = field(default_factory=list)
    _reported: set[str] = field(default_factory=set)

    def admit(self, stream: str, stamp_ns: int, now_ns: int | None, wall_ns: int,
              tolerance_ns: int | None = None) -> bool:
        """True if the message of ``stream`` stamped ``stamp_ns`` may be taken by a consumer
        whose now is ``now_ns`` (None: not known yet, everything is taken); ``wall_ns``: a
        monotonic wall clock (times the recovery); ``tolerance_ns``: this stream's own, if
        not the guard's."""
        if now_ns is None:
            return True
        tolerance = self.tolerance_ns if tolerance_ns is None else tolerance_ns
        state = self._streams.get(stream)
        if state is None:
            state = self._streams[stream] = _Stream()
        lead = stamp_ns - now_ns
        if lead - state.offset_ns <= tolerance:
            state.refused_since, state.refused_run = None, 0
            return True
        if state.refused_since is None:
            state.refused_since = wall_ns
        state.refused_run += 1
        if (state.refused_run >= self.recover_messages
                and wall_ns - state.refused_since >= self.recover_ns):
            state.offset_ns = lead
            state.refused_since, state.refused_run = None, 0
            self.recovered += 1
            self._report(f'{stream}: stamps {lead / _NS_PER_S:.6g} s ahead of this node\'s clock '
                         f'for {self.recover_ns / _NS_PER_S:g} s and every message: taken as a '
                         'clock step, the stream is taken again', key=f'{stream}/recovered')
            return True
        self.refused += 1
        self._report(f'{stream}: message stamped {lead / _NS_PER_S:.6g} s ahead of this node\'s '
                     f'clock refused (at most {tolerance / _NS_PER_S:g} s ahead taken); '
                     'the valid messages are taken', key=stream)
        return False

    def back_on_clock(self, stream: str, held_ns: int, stamp_ns: int, now_ns: int | None) -> bool:
        """A message of ``stream`` stamped ``stamp_ns``, older than the value held (stamped
        ``held_ns``), that a consumer would not take: True when the held value is stamped
        beyond the tolerance ahead of now (it came in through a clock step) and this message
        is within it — the stream's clock went back (the real plant restarted after a stream
        stamped ahead was taken; a host clock corrected again): the stream's offset is
        forgotten and the consumer takes the message instead of holding the stepped value
        until real time passes it. Otherwise False (an out-of-order message: not taken)."""
        if now_ns is None:
            return False
        if held_ns - now_ns <= self.tolerance_ns or stamp_ns - now_ns > self.tolerance_ns:
            return False
        self._streams.pop(stream, None)
        self.returned += 1
        self._report(f'{stream}: stamped {((stamp_ns - held_ns) / _NS_PER_S):.6g} s before the '
                     'value held, which was ahead of this node\'s clock: taken as the stream\'s '
                     'clock going back', key=f'{stream}/returned')
        return True

    def reset(self, stream: str | None = None) -> None:
        """Forget the offsets and runs (of one stream): a new session of the clock."""
        if stream is None:
            self._streams.clear()
        else:
            self._streams.pop(stream, None)

    def _report(self, text: str, key: str) -> None:
        if key not in self._reported:
            self._reported.add(key)
            self._reports.append(text)

    def take_report(self) -> list[str]:
        """Lines to log: the first refusal of each stream and each clock step taken, once
        (until ``rearm_reports``)."""
        out, self._reports = self._reports, []
        return out

    def rearm_reports(self) -> None:
        """Report again (a node calls it once per diagnostics period: a rate-limited log)."""
        self._reported.clear()


#: what a user does about an input refused as older than the one held (``rejected_past``):
#: on the wall clock, stamp it now; on a simulated clock, with the loop's /clock time
PAST_FIX_WALL = "stamp it now (ros2 topic pub: '{header: auto, ...}')"
PAST_FIX_SIM = "stamp it with the loop's /clock time"
