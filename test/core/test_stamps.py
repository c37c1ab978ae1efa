"""Messages stamped in the future are refused, a clock step is taken within a bound, and a
message with too many names is refused before its names are decoded (core/stamps.py)."""
import math
import time

import pytest

from tank_control.core.stamps import (
    FUTURE_STAMP_SAMPLES,
    LOCKSTEP_AHEAD_TICKS,
    MAX_NAMES,
    RECOVER_MESSAGES,
    RECOVER_S,
    FutureStamps,
    future_tolerance_ns,
)
from tank_control.nodes.cdr import JointStateCdr
from tank_control.nodes.messages import ChannelFilter, parse_signal

S = 1_000_000_000
MS = 1_000_000


def test_default_tolerance_is_a_few_sample_times_and_lockstep_covers_the_lookahead():
    assert future_tolerance_ns(0.0, 0.1) == FUTURE_STAMP_SAMPLES * 100 * MS
    assert future_tolerance_ns(None, 0.1) == FUTURE_STAMP_SAMPLES * 100 * MS
    assert future_tolerance_ns(2.5, 0.1) == 2500 * MS
    assert future_tolerance_ns(0.0, 0.1, lockstep=True) == LOCKSTEP_AHEAD_TICKS * 100 * MS
    assert future_tolerance_ns(60.0, 0.1, lockstep=True) == 60 * S


def test_one_message_far_ahead_is_refused_and_the_stream_goes_on():
    guard = FutureStamps(tolerance_ns=500 * MS)
    wall = 0
    assert guard.admit('measurement', 10 * S, 10 * S, wall)
    assert guard.admit('measurement', 10 * S + 500 * MS, 10 * S, wall)   # at the tolerance
    for lead in (10 * S, 3600 * S, 1_000_000 * S, 4_102_444_800 * S):   # ... 2100 (int64 ns)
        assert not guard.admit('measurement', 10 * S + lead, 10 * S, wall)
    assert guard.refused == 4
    # the valid messages keep coming and are taken; the refusals are reported once
    for k in range(1, 100):
        wall += 10 * MS
        assert guard.admit('measurement', 10 * S + k * 10 * MS, 10 * S + k * 10 * MS, wall)
    reports = guard.take_report()
    assert len(reports) == 1 and 'measurement' in reports[0] and 'refused' in reports[0]
    assert guard.take_report() == []
    assert guard.recovered == 0


def test_nothing_is_refused_before_the_consumer_knows_its_now():
    guard = FutureStamps(tolerance_ns=1)
    assert guard.admit('setpoint', 10**18, None, 0)
    assert guard.refused == 0


def test_stray_messages_between_valid_ones_never_become_a_clock_step():
    """A writer sending far-future messages all along, between the genuine ones, is refused
    every time: each valid message ends the run of refusals."""
    guard = FutureStamps(tolerance_ns=50 * MS)
    for k in range(1000):                   # 10 s of a 100 Hz stream, a stray after each
        now, wall = k * 10 * MS, k * 10 * MS
        assert guard.admit('measurement', now, now, wall)
        assert not guard.admit('measurement', now + 3600 * S, now, wall)
    assert guard.refused == 1000 and guard.recovered == 0


@pytest.mark.parametrize('period_ms', [10, 100, 1000])
def test_a_clock_step_is_taken_within_the_documented_bound(period_ms):
    """The consumer's clock stepped back one hour (or the plant restarted on a host an hour
    ahead): every message of the stream is now an hour ahead. It is taken again at most
    ``max(RECOVER_S + p, (RECOVER_MESSAGES - 1)·p)`` after the first refused one (p: the
    stream's period), and from then on with the offset; a message far beyond the new offset
    is still refused."""
    p = period_ms * MS
    guard = FutureStamps(tolerance_ns=5 * p)
    step = 3600 * S
    first_refused = None
    k = 0
    while True:
        wall = now = k * p
        if guard.admit('measurement', now + step, now, wall):
            break
        first_refused = wall if first_refused is None else first_refused
        k += 1
        assert k < 10_000
    bound = max(RECOVER_S * S + p, (RECOVER_MESSAGES - 1) * p)
    assert first_refused == 0 and 0 < wall - first_refused <= bound
    assert guard.recovered == 1 and guard.refused == k
    for j in range(k + 1, k + 50):          # the stream goes on with its offset
        assert guard.admit('measurement', j * p + step, j * p, j * p)
    assert not guard.admit('measurement', j * p + step + 3600 * S, j * p, j * p)
    assert any('clock step' in line for line in guard.take_report())


def test_streams_recover_independently_and_a_reset_forgets_the_offset():
    guard = FutureStamps(tolerance_ns=0, recover_ns=0, recover_messages=2)
    assert not guard.admit('setpoint', 100, 0, 0)
    assert guard.admit('setpoint', 100, 0, 1)              # the second: a step
    assert not guard.admit('measurement', 100, 0, 2)       # another stream: its own run
    assert guard.admit('setpoint', 101, 1, 3)
    guard.reset()
    assert not guard.admit('setpoint', 101, 1, 4)


def test_a_stream_taken_through_a_step_is_taken_again_when_its_clock_goes_back():
    """A stream stamped an hour ahead is taken as a clock step; then its clock goes back (the
    real plant restarted): a message on this node's clock, older than the stepped value held,
    is taken at once (the offset forgotten) instead of waiting an hour. An out-of-order
    message within the tolerance, or one while the held value is on this node's clock, is
    still not taken (``back_on_clock`` is False), and a stepped stream that goes on is not
    treated as going back."""
    guard = FutureStamps(tolerance_ns=500 * MS, recover_ns=RECOVER_S * S,
                         recover_messages=RECOVER_MESSAGES)
    now, wall, step = 10 * S, 0, 3600 * S
    for k in range(RECOVER_MESSAGES + 20):        # refused, then taken as a step
        wall = k * 100 * MS
        taken = guard.admit('manipulated', now + step + wall, now + wall, wall)
    assert taken and guard.recovered == 1
    held, now = now + step + wall, now + wall
    assert not guard.back_on_clock('manipulated', held, held + 100 * MS, now)   # goes on
    assert guard.back_on_clock('manipulated', held, now + 100 * MS, now)        # went back
    assert guard.returned == 1
    assert any('going back' in line for line in guard.take_report())
    # the offset is gone: a message an hour ahead is refused again
    assert not guard.admit('manipulated', now + step, now, wall + 200 * MS)
    # an ordinary out-of-order message (the held value on this node's clock) is not taken
    assert not guard.back_on_clock('manipulated', now + 200 * MS, now + 100 * MS, now)
    assert not guard.back_on_clock('manipulated', held, now, None)   # now not known


def test_reports_are_rate_limited_and_rearmed():
    guard = FutureStamps(tolerance_ns=0)
    for _ in range(100):
        guard.admit('manipulated', 10, 0, 0)
    assert len(guard.take_report()) == 1
    guard.admit('manipulated', 10, 0, 0)
    assert guard.take_report() == []
    guard.rearm_reports()
    guard.admit('manipulated', 10, 0, 0)
    assert len(guard.take_report()) == 1


def test_a_message_with_too_many_names_is_refused_before_decoding_them():
    names = [f'x{i}' for i in range(100_000)]
    data = JointStateCdr(names).encode_ns(0, [0.0] * len(names))
    start = time.perf_counter()
    with pytest.raises(ValueError, match=f'100000 channel names, at most {MAX_NAMES}'):
        parse_signal(data)
    assert time.perf_counter() - start < 0.5        # no per-name work (decoding took ~0.1 s)
    small = JointStateCdr(['u']).encode_ns(5, [1.0])
    assert parse_signal(small) == (5, '', ('u',), (1.0,))


def test_channel_filter_counts_unknown_names_and_keeps_its_reasons_bounded():
    flt = ChannelFilter(('u',))
    names = [f'x{i}' for i in range(MAX_NAMES - 1)] + ['u']
    data = JointStateCdr(names).encode_ns(0, [1.0] * len(names))
    t_ns, _, accepted, new = flt.accept('manipulated', data)
    assert t_ns == 0 and accepted == {'u': 1.0}
    assert flt.unknown == MAX_NAMES - 1 and flt.ignored == MAX_NAMES - 1
    assert len(new) == 1 and f'and {MAX_NAMES - 4} more' in new[0]
    for _ in range(3):                      # the same kind again: counted, not logged
        _, _, _, new = flt.accept('manipulated', data)
        assert new == []
    assert flt.unknown == 4 * (MAX_NAMES - 1) and len(flt.reasons) == 1
    big = JointStateCdr([f'y{i}' for i in range(MAX_NAMES + 1)])
    t_ns, _, accepted, new = flt.accept('manipulated', big.encode_ns(0, [0.0] * (MAX_NAMES + 1)))
    assert t_ns is None and accepted == {} and flt.oversized == 1 and len(new) == 1
    _, _, _, new = flt.accept('manipulated', JointStateCdr(['u']).encode_ns(0, [math.nan]))
    assert len(new) == 1 and 'non-finite' in new[0]
    flt.rearm()
    _, _, _, new = flt.accept('manipulated', data)
    assert len(new) == 1
