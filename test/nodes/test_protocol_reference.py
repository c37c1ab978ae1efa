"""The reference's clock protocol (nodes/protocol/reference.py) without ROS: what it publishes
for each /clock tick or wall instant. The DDS tests (test_reference_node.py) keep one run per
mode end to end."""
from __future__ import annotations

from support.held import REFERENCE
from tank_control.core.scenario import reference_setup
from tank_control.nodes.cdr import signal_from_cdr
from tank_control.nodes.clock import Held
from tank_control.nodes.protocol.reference import (LockstepReference, SimReference,
                                                   WallReference, reference_clock)

T = 100_000_000          # the plant's tick [ns]


class Host:
    def __init__(self) -> None:
        self.reference = reference_setup(REFERENCE).reference
        self.applied: list[float] = []
        self.logged: list[str] = []

    def apply_pending(self, t: float) -> None:
        self.applied.append(t)

    def info(self, text: str) -> None:
        self.logged.append(text)


def decoded(messages, topic):
    """(stamp, values) of the messages of ``topic``."""
    out = []
    for t, msg in messages:
        if t == topic:
            stamp, _, _, values = signal_from_cdr(msg)
            out.append((stamp, values))
    return out


def test_the_mode_picks_the_protocol_once():
    assert reference_clock('lockstep', True) is LockstepReference
    assert reference_clock('sim', False) is SimReference
    assert reference_clock('wall', True) is SimReference      # use_sim_time: /clock ticks
    assert reference_clock('wall', False) is WallReference


def test_lockstep_lookahead_0_answers_every_tick_on_its_own_clock():
    """``lockstep.lookahead: 0``: each /clock answered with the values of that tick, stamped
    with it (a message per tick, the held value when nothing changed); a re-sent tick gets
    the same messages again."""
    ref = LockstepReference(Host(), 0)
    first = ref.clock(0)
    assert decoded(first, 'setpoint') == [(0, (1.0,))]
    assert ref.clock(0) == first                              # the plant re-sent tick 0
    answers = [decoded(ref.clock(k * T), 'setpoint') for k in range(1, 6)]
    assert answers == [[(k * T, (v,))] for k, v in zip(range(1, 6), (1.0, 1.0, 2.0, 2.0, 2.0))]


def test_lockstep_publishes_the_schedules_ahead_once_per_change_and_again_on_resend():
    """lookahead 6: on /clock t_k the schedules are known through t_k+6 under zero-order hold —
    a message at each change and one at the horizon only when the last one is older than
    t_k+1; read back by zero-order hold (clock.Held, the consumers' side) they equal the
    schedules at every tick; a re-sent tick gets every message from the one in force at it."""
    ref = LockstepReference(Host(), 6)
    sent = []
    held = {'setpoint': Held(), 'disturbance': Held()}
    for k in range(21):
        messages = ref.clock(k * T)
        sent += messages
        for topic, msg in messages:
            stamp, _, names, values = signal_from_cdr(msg)
            held[topic].put(stamp, dict(zip(names, values)))
        # every tick up to the next one is known once its /clock is answered (tick 0: the
        # tick period is not known yet, tick 0 alone)
        assert all(h.through >= (k + 1 if k else 0) * T for h in held.values()), k
    ticks = range(22)
    assert [held['setpoint'].values(k * T)['y'] for k in ticks] == [1.0] * 3 + [2.0] * 19
    assert max(abs(held['disturbance'].values(k * T)['v'] - max(-0.5, min(0.0, -(k - 5) / 10)))
               for k in ticks) < 1e-12
    assert [s // T for s, _ in decoded(sent, 'setpoint')] == [0, 3, 9, 15, 21]
    assert [s // T for s, _ in decoded(sent, 'disturbance')] == [0, 6, 7, 8, 9, 10, 16, 22]
    again = ref.clock(20 * T)
    assert [s // T for s, _ in decoded(again, 'setpoint')] == [15, 21]
    assert decoded(again, 'setpoint') == [m for m in decoded(sent, 'setpoint') if m[0] >= 15 * T]


def test_lockstep_a_clock_that_goes_back_starts_a_new_run():
    host = Host()
    ref = LockstepReference(host, 2)
    for k in range(5):
        ref.clock(k * T)
    restarted = ref.clock(0)
    assert decoded(restarted, 'setpoint') == [(0, (1.0,))]
    # each run's first tick is logged (a restart the reference never saw shows in its log)
    assert host.logged == ['first /clock tick 0 s: answering the plant',
                           '/clock restarted: answering a new run',
                           'first /clock tick 0 s: answering the plant']


def test_sim_answers_only_the_current_tick_once():
    """In sim the plant and controller use the latest message: it must be tick k's, nothing
    ahead; a re-sent tick gets the very same messages (not evaluated again)."""
    host = Host()
    ref = SimReference(host, 6)
    for k in range(5):
        messages = ref.clock(k * T)
        assert [s for s, _ in decoded(messages, 'setpoint')] == [k * T]
        assert [s for s, _ in decoded(messages, 'disturbance')] == [k * T]
        assert ref.clock(k * T) == messages
    assert decoded(ref.clock(4 * T), 'setpoint') == [(4 * T, (2.0,))]
    assert len(host.applied) == 5                              # one evaluation per tick


def test_wall_publishes_each_instant_once_lead_early_stamped_with_it():
    """wall: instant j of the plant's grid is published ``wall.lead`` before it (at most half a
    period), stamped ``origin + j·T``, once; before tick 0 the wait is until instant 0."""
    ref = WallReference(Host(), 0)
    origin = 5_000_000_000
    assert ref.origin(origin) and not ref.origin(origin)
    messages, wait = ref.timer(origin - 50_000_000, T, 10_000_000)
    assert messages == [] and wait == 40_000_000
    messages, wait = ref.timer(origin - 10_000_000, T, 10_000_000)       # instant 0, lead early
    assert decoded(messages, 'setpoint') == [(origin, (1.0,))] and wait == T
    assert ref.timer(origin + 20_000_000, T, 10_000_000)[0] == []        # published already
    messages, wait = ref.timer(origin + 3 * T - 10_000_000, T, 200_000_000)   # lead <= T/2
    assert decoded(messages, 'setpoint') == [(origin + 3 * T, (2.0,))]
    assert wait == 60_000_000          # 3T + 40 ms reached: instant 4 (lead 50 ms) in 60 ms
