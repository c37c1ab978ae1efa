"""The consumers' side of the reference's lockstep streams (``nodes/clock.Held``, zero-order
hold): what a plant or controller knows of a tick, from messages published once per change and
``lockstep.lookahead`` ticks ahead, re-sent, or from a restarted stream."""
from __future__ import annotations

from tank_control.nodes.clock import Held, StampedInbox

T = 100


def test_a_message_holds_until_the_next_and_a_tick_is_known_once_one_at_or_after_it_came():
    held = Held()
    held.put(0, {'y': 1.0})
    held.put(3 * T, {'y': 2.0})
    assert held.through == 3 * T
    assert [held.values(k * T)['y'] for k in range(5)] == [1.0, 1.0, 1.0, 2.0, 2.0]
    inbox = StampedInbox({'setpoint': ('y',), 'measurement': ('y',)}, held=('setpoint',))
    inbox.put('setpoint', 0, {'y': 1.0})
    inbox.put('setpoint', 3 * T, {'y': 2.0})
    inbox.put('measurement', 2 * T, {'y': 0.5})
    assert inbox.complete(2 * T) and inbox.values(2 * T, 'setpoint') == {'y': 1.0}
    inbox.put('measurement', 4 * T, {'y': 0.5})
    assert not inbox.complete(4 * T)                      # nothing stamped at or after 4 yet
    assert inbox.missing(4 * T) == ['setpoint']
    inbox.put('setpoint', 9 * T, {'y': 2.0})                # the hold at the horizon
    assert inbox.complete(4 * T) and inbox.values(4 * T, 'setpoint') == {'y': 2.0}


def test_folding_the_past_keeps_the_value_in_force_and_channels_carry_over():
    held = Held()
    held.put(0, {'a': 1.0, 'b': 5.0})
    held.put(2 * T, {'a': 2.0})
    held.put(4 * T, {'a': 3.0, 'b': 6.0})
    held.fold_until(3 * T)
    assert held.values(3 * T) == {'a': 2.0, 'b': 5.0}
    assert held.values(4 * T) == {'a': 3.0, 'b': 6.0}


def test_a_resend_restarts_the_stream_at_its_stamp_and_the_rest_comes_again():
    """The plant re-sent tick 5; the reference re-sends every message from the one in force at
    5 on (stamped 3, then 7, 11): the knowledge shrinks to 3 at the first and grows again."""
    held = Held()
    for stamp, value in ((0, 1.0), (3 * T, 2.0), (7 * T, 3.0), (11 * T, 3.0)):
        held.put(stamp, {'y': value})
    held.fold_until(5 * T)
    held.put(3 * T, {'y': 2.0})
    assert held.through == 3 * T and held.values(5 * T) == {'y': 2.0}
    held.put(7 * T, {'y': 3.0})
    held.put(11 * T, {'y': 3.0})
    assert held.through == 11 * T
    assert [held.values(k * T)['y'] for k in (5, 6, 7, 11)] == [2.0, 2.0, 3.0, 3.0]


def test_a_new_stream_replaces_what_the_old_one_said_of_the_future():
    """A restarted reference starts at the plant's tick with its own schedule: what the old one
    had published ahead is dropped."""
    held = Held()
    held.put(0, {'y': 1.0})
    held.put(6 * T, {'y': 4.0})          # the old reference's step, published ahead
    held.put(4 * T, {'y': 1.0})          # the new one's first message, at tick 4
    assert held.through == 4 * T
    held.put(10 * T, {'y': 1.0})         # its hold: no step at 6
    assert held.values(6 * T) == {'y': 1.0}


def test_a_new_plant_session_forgets_the_old_future_but_not_a_new_stream_that_came_first():
    inbox = StampedInbox({'setpoint': ('y',)}, held=('setpoint',))
    inbox.put('setpoint', 0, {'y': 1.0})
    inbox.put('setpoint', 30 * T, {'y': 1.0})
    inbox.drop_before(20 * T)
    inbox.drop_from(20 * T)              # tick 0 after 20 answered: the plant restarted
    assert not inbox.complete(0)         # the old stream's knowledge is gone
    inbox.put('setpoint', 0, {'y': 7.0})
    assert inbox.complete(0) and inbox.values(0, 'setpoint') == {'y': 7.0}
    # the reference's new tick-0 message came before the plant's new tick 0
    inbox = StampedInbox({'setpoint': ('y',)}, held=('setpoint',))
    inbox.put('setpoint', 0, {'y': 1.0})
    inbox.put('setpoint', 30 * T, {'y': 1.0})
    inbox.drop_before(20 * T)
    inbox.put('setpoint', 0, {'y': 7.0})
    inbox.drop_from(20 * T)
    assert inbox.complete(0) and inbox.values(0, 'setpoint') == {'y': 7.0}
