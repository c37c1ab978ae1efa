"""Values announced ahead of their instant (the reference's ``wall.lead``) take effect at it."""
from tank_control.nodes.clock import Scheduled


def test_values_take_effect_at_their_stamp_in_stamp_order():
    ahead, held = Scheduled(), {'y': 0.0}
    ahead.put(300, {'y': 3.0})
    ahead.put(100, {'y': 1.0})
    ahead.put(200, {'y': 2.0, 'z': 5.0})
    ahead.release(99, held)
    assert held == {'y': 0.0} and len(ahead) == 3        # nothing due before its stamp
    ahead.release(250, held)
    assert held == {'y': 2.0, 'z': 5.0} and len(ahead) == 1   # 100 then 200: the later wins
    ahead.release(300, held)
    assert held == {'y': 3.0, 'z': 5.0} and len(ahead) == 0


def test_of_two_values_with_one_stamp_the_later_arrival_wins():
    ahead, held = Scheduled(), {}
    ahead.put(100, {'y': 1.0})
    ahead.put(100, {'y': 1.5})
    ahead.release(100, held)
    assert held == {'y': 1.5}
    ahead.put(500, {'y': 9.0})
    ahead.clear()
    ahead.release(1000, held)
    assert held == {'y': 1.5}
