"""signal_bridge_node's mapping without ROS (core/signal_bridge.py): stamps (the driver's, or
the wall clock), the time origin, and every refusal counted and reported once per period."""
from __future__ import annotations

import math

import pytest

from tank_control.core import signal_bridge as sb
from tank_control.core.params import ConfigError

S = 1_000_000_000
BASE = {'measurement.channels': ['y', 'T'], 'measurement.y.topic': '/tank/level',
        'measurement.T.topic': '/tank/temperature', 'measurement.T.type': 'Temperature',
        'manipulated.channels': ['u'], 'manipulated.u.topic': '/valve/command',
        'sample_time': 0.1}


def mapping(**values) -> sb.SignalMapping:
    return sb.SignalMapping(sb.settings_from({**BASE, **values}, {'u': (0.0, 10.0)}))


def test_a_value_without_a_stamp_is_stamped_on_arrival_and_announces_the_origin_first():
    m = mapping()
    now = 1000 * S + 37_000_000
    assert m.measurement('y', 1.5, None, now, 0) is None        # before the origin it announces
    origin = m.new_origin
    assert origin == m.origin_ns and m.counters['before_origin'] == 1
    # on the first value's grid shifted by half a sample time, at least 0.2 s ahead
    assert (origin - (now - 50_000_000)) % 100_000_000 == 0
    assert now + 200_000_000 <= origin < now + 300_000_000
    later = origin + 1
    assert m.measurement('y', 2.5, 0, later, 0) == (later, {'y': 2.5})   # 0 = no stamp
    assert m.counters['receive_stamps'] == 2 and m.counters['published'] == 1


def test_a_stamped_scalar_keeps_its_driver_s_stamp():
    m = mapping(announce_origin=False)
    assert m.origin_ns == 0 and m.new_origin is None
    assert m.measurement('T', 21.5, 5 * S, 5 * S + 3_000_000, 0) == (5 * S, {'T': 21.5})
    assert m.counters['receive_stamps'] == 0


def test_non_finite_future_and_older_values_are_refused_counted_and_reported_once_a_period():
    m = mapping(announce_origin=False)
    now = 100 * S
    assert m.measurement('T', 20.0, now, now, 0) is not None
    for bad in (math.nan, math.inf, -math.inf):
        assert m.measurement('T', bad, now + 1, now + 1, 0) is None
    assert m.counters['nonfinite'] == 3
    (reason,) = m.take_reasons()
    assert reason.startswith('measurement.T: non-finite value nan refused')
    # more than max_future_stamp (0: 5 sample times) ahead of the wall clock
    assert m.measurement('T', 20.0, now + 600_000_000, now + 2, 0) is None
    assert m.counters['rejected_future'] == 1
    assert 'ahead' in m.take_reasons()[0]
    assert m.measurement('T', 20.0, now - 1, now + 3, 0) is None          # older than the last
    assert m.counters['out_of_order'] == 1
    assert m.take_reasons() == ['measurement.T: a value stamped at or before the last one '
                                '(1e-09 s older) refused']
    assert m.measurement('T', math.nan, now + 4, now + 4, 0) is None
    assert m.take_reasons() == []                                # reported this period already
    m.rearm()
    assert m.measurement('T', math.nan, now + 5, now + 5, 0) is None
    assert any('non-finite' in r for r in m.take_reasons())      # reported again
    assert m.measurement('T', 20.5, now + 6, now + 6, 0) == (now + 6, {'T': 20.5})
    level, text = m.status()
    assert level == 'warn' and '5 non-finite values refused' in text
    assert mapping().status() == ('ok', 'ok')


def test_manipulated_values_are_written_per_channel_and_hostile_ones_never_reach_the_driver():
    m = mapping()
    assert m.manipulated(10, ['u'], [2.5]) == [('u', 2.5, 10)]
    assert m.manipulated(11, ['u', 'w'], [3.0, 1.0]) == [('u', 3.0, 11)]
    assert m.counters['unknown_channels'] == 1
    assert m.manipulated(12, ['u'], [math.nan]) == []
    assert m.manipulated(13, ['u'], [10.5]) == []              # outside range.u [0, 10]
    assert m.manipulated(9, ['u'], [1.0]) == []                # older than the last
    assert m.manipulated(14, ['u', 'u'], [1.0, 2.0]) == []     # malformed
    assert m.manipulated(15, ['u'], [1.0, 2.0]) == []
    assert (m.counters['nonfinite'], m.counters['out_of_range'], m.counters['out_of_order'],
            m.counters['malformed'], m.counters['written']) == (1, 1, 1, 2, 2)
    reasons = m.take_reasons()
    assert any('outside' in r or 'range' in r for r in reasons), reasons
    assert len([r for r in reasons if 'malformed' in r]) == 1   # once per period


@pytest.mark.parametrize('values, error', [
    ({'measurement.y.topic': 'measurement'}, "measurement.y.topic: 'measurement' is one of the "
                                             "loop's own topics"),
    ({'measurement.y.topic': ''}, 'measurement.y.topic: missing'),
    ({'measurement.y.topic': '/a b'}, "'/a b' is not a topic name"),
    ({'measurement.T.type': 'Float32'}, "measurement.T.type: 'Float32'; allowed one of Float64"),
    ({'manipulated.u.topic': '/tank/level'}, "'/tank/level' is also measurement.y.topic"),
    ({'measurement.channels': [''], 'manipulated.channels': ['']}, 'no channel'),
    ({'measurement.channels': ['y', 'y']}, 'repeated name'),
    ({'sample_time': 0.0}, 'sample_time'),
])
def test_settings_refuse_with_one_line_naming_the_parameter(values, error):
    with pytest.raises(ConfigError, match=error.replace('(', r'\(').replace(')', r'\)')):
        sb.settings_from({**BASE, **values})


def test_parameters_are_declared_with_types_choices_and_ranges():
    specs = {s.name: s for s in sb.specs(BASE, {'u': (0.0, 10.0)})}
    assert specs['measurement.T.type'].choices == tuple(sb.TYPES)
    assert specs['measurement.y.topic'].read_only
    assert specs['range.u'].default == [0.0, 10.0]
    assert (specs['sample_time'].min, specs['sample_time'].max) == (0.001, 3600.0)
    assert {'max_future_stamp', 'diagnostics_period', 'announce_origin'} <= set(specs)


def test_publish_sample_sends_every_channel_at_each_instant_with_its_latest_value_before_it():
    """A controller of several outputs samples on a message holding all of them
    (controller_node, docs/nodes.md): ``measurement.publish: sample`` resamples the drivers on
    the loop's grid, never putting a value under an instant before its own stamp."""
    m = mapping(**{'measurement.publish': 'sample'})
    now = 50 * S
    assert m.measurement('y', 1.0, None, now, 0) is None          # announces the origin
    origin = m.new_origin
    ts = 100_000_000
    assert m.sample(origin - 1) is None                            # before the origin
    assert m.measurement('y', 2.0, None, origin + 10, 0) is None   # held, not published alone
    assert m.measurement('T', 20.0, origin + 20, origin + 20, 0) is None
    assert m.sample(origin + ts - 1) is None       # instant 0: no value stamped at or before it
    assert m.counters['incomplete_samples'] == 1
    assert m.sample(origin + ts - 1) is None and m.counters['incomplete_samples'] == 1   # once
    assert m.measurement('T', 21.0, origin + ts + 5, origin + ts + 5, 0) is None   # after inst 1
    assert m.sample(origin + ts) == (origin + ts, {'y': 2.0, 'T': 20.0})
    assert m.sample(origin + ts + 50) is None                      # each instant once
    assert m.sample(origin + 3 * ts + 1) == (origin + 3 * ts, {'y': 2.0, 'T': 21.0})
    assert m.counters['published'] == 2


def test_publish_sample_needs_the_bridge_s_own_origin():
    with pytest.raises(ConfigError, match='measurement.publish: sample needs announce_origin'):
        sb.settings_from({**BASE, 'measurement.publish': 'sample', 'announce_origin': False})
