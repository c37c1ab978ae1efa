"""Reference schedules: steps, rate-limited ramps ([DeadTimeNotes] Fig. 1.15), limits, live changes."""
from __future__ import annotations

import pytest

from tank_control.core.reference import (
    ChannelSchedule,
    Reference,
    channel_specs,
    reference_from_params,
)


def ramp_001() -> Reference:
    """[DeadTimeNotes] Fig. 1.15: setpoint 0 → 100 reached in 25 s (rate 4/s), starting at t = 10 s."""
    return reference_from_params({
        'setpoint.channels': ['y'],
        'setpoint.y.times': [0.0, 10.0], 'setpoint.y.values': [0.0, 100.0],
        'setpoint.y.ramp_rate': 4.0,
        'disturbance.channels': ['v'], 'disturbance.v.value': -0.1,
    })


def test_step_schedule_holds_each_value_from_its_time():
    s = ChannelSchedule(times=(0.0, 5.0, 8.0), values=(1.0, 2.0, -3.0))
    assert [s.at(t) for t in (0.0, 4.999, 5.0, 7.0, 8.0, 1e6)] == [1, 1, 2, 2, -3, -3]


def test_first_value_holds_before_the_first_time():
    assert ChannelSchedule(times=(3.0,), values=(7.0,)).at(0.0) == 7.0


def test_ramp_reaches_the_target_in_25_s_as_in_001():
    ref = ramp_001()
    # Linear between 10 s and 35 s, then constant: the closed form of a rate limit.
    for t in (0.0, 10.0, 12.5, 22.0, 34.0, 35.0, 60.0):
        expected = min(max(4.0 * (t - 10.0), 0.0), 100.0)
        assert ref.setpoints(t)[0] == pytest.approx(expected, abs=1e-12)
    assert ref.disturbances(3.0).tolist() == [-0.1]


def test_ramp_reverses_from_where_it_is():
    # Target 10 at t=0 (from 0 at rate 1), back to 0 at t=4: up to 4, then down at 1/s.
    s = ChannelSchedule(times=(0.0, 0.0, 4.0), values=(0.0, 10.0, 0.0), ramp_rate=1.0)
    assert [s.at(t) for t in (2.0, 4.0, 6.0, 8.0, 9.0)] == [2.0, 4.0, 2.0, 0.0, 0.0]


def test_out_of_range_values_are_rejected_with_the_channel_and_range():
    with pytest.raises(ValueError, match=r'setpoint\.y\.values: 150 is out of range; allowed \[0, 120\]'):
        reference_from_params({'setpoint.channels': ['y'], 'setpoint.y.times': [0.0, 1.0],
                               'setpoint.y.values': [0.0, 150.0], 'setpoint.y.min': 0.0,
                               'setpoint.y.max': 120.0})


@pytest.mark.parametrize('params, fragment', [
    ({'setpoint.y.times': [0.0, 1.0], 'setpoint.y.values': [1.0]}, 'equal lengths'),
    ({'setpoint.y.times': [2.0, 1.0], 'setpoint.y.values': [1.0, 2.0]}, 'non-decreasing'),
    ({'setpoint.y.value': 2.0, 'setpoint.y.values': [1.0]}, 'not both'),
    ({'setpoint.y.ramp_rate': -1.0}, 'ramp_rate'),
    ({'setpoint.z.value': 1.0}, "channel 'z' is not in setpoint.channels"),
])
def test_malformed_schedules_are_rejected(params, fragment):
    with pytest.raises(ValueError, match=fragment):
        reference_from_params({'setpoint.channels': ['y'], **params})


def test_live_override_starts_a_ramp_from_the_current_value_and_drops_later_entries():
    ref = ramp_001()
    assert ref.set_value('setpoint', 'y', 50.0, t=40.0) is None
    assert ref.setpoints(40.0)[0] == 100.0
    assert ref.setpoints(45.0)[0] == pytest.approx(80.0)
    assert ref.setpoints(1000.0)[0] == 50.0


def test_rejected_live_change_leaves_the_channel_untouched():
    ref = reference_from_params({'setpoint.channels': ['y'], 'setpoint.y.value': 1.0,
                                 'setpoint.y.max': 10.0})
    reason = ref.set_value('setpoint', 'y', 11.0, t=1.0)
    assert reason == 'setpoint.y.value: 11 is out of range; allowed [-1e+09, 10]'
    assert ref.update('setpoint', 'y', {'times': [0.0, 1.0]}) is not None   # lengths differ
    assert ref.update('setpoint', 'nope', {'value': 1.0}).startswith('setpoint.nope: unknown channel')
    assert ref.setpoints(5.0).tolist() == [1.0]


def test_new_schedule_replaces_the_old_one():
    ref = ramp_001()
    assert ref.update('setpoint', 'y', {'times': [0.0, 1.0], 'values': [5.0, 6.0],
                                        'ramp_rate': 0.0}) is None
    assert ref.setpoints(0.5).tolist() == [5.0] and ref.setpoints(2.0).tolist() == [6.0]


def test_param_specs_describe_every_channel_field_with_the_schedule_as_default():
    specs = {s.name: s for s in channel_specs(ramp_001())}
    assert specs['setpoint.y.values'].default == [0.0, 100.0]
    assert specs['setpoint.y.ramp_rate'].default == 4.0
    assert specs['disturbance.v.value'].default == -0.1
    assert specs['setpoint.channels'].read_only
    assert specs['setpoint.y.ramp_rate'].check(-1.0) is not None


def test_declared_parameters_of_a_reference_build_the_same_reference():
    """What the node declares (value = the schedule at t = 0 beside times/values, as
    `ros2 param dump` writes it) reads back as the same schedules."""
    ref = ramp_001()
    declared = {s.name: s.default for s in channel_specs(ref)}
    again = reference_from_params(declared)
    for kind, names in (('setpoint', ref.setpoint_names), ('disturbance', ref.disturbance_names)):
        assert [again.schedule(kind, n) for n in names] == [ref.schedule(kind, n) for n in names]


def test_limit_changes_are_judged_on_the_present_and_future_not_the_past():
    ref = reference_from_params({'setpoint.channels': ['y'], 'setpoint.y.times': [0.0, 5.0, 20.0],
                                 'setpoint.y.values': [0.0, 50.0, 60.0], 'setpoint.y.ramp_rate': 2.0})
    # At t = 10 the ramp is at 10 (from 0 toward 50 since t = 5): 0 is past, 10 is current.
    assert ref.update('setpoint', 'y', {'min': 11.0}, t=10.0) == \
        'setpoint.y.values: 10 is out of range; allowed [11, 1e+09]'
    assert ref.update('setpoint', 'y', {'min': 5.0}, t=10.0) is None
    # The ramp and the later scheduled change are unaffected.
    assert [ref.setpoints(t)[0] for t in (10.0, 15.0, 30.0, 40.0)] == [10.0, 20.0, 50.0, 60.0]
    assert ref.update('setpoint', 'y', {'max': 55.0}, t=12.0).startswith('setpoint.y.values: 60')


def test_a_misspelt_channel_field_is_refused_with_the_nearest_name():
    with pytest.raises(ValueError, match='setpoint.y.valeus: unknown parameter; did you mean '
                                         'setpoint.y.values'):
        reference_from_params({'setpoint.channels': ['y'], 'setpoint.y.times': [0.0],
                               'setpoint.y.valeus': [1.0]})
    with pytest.raises(ValueError, match='setpoint.chanels: unknown parameter; did you mean '
                                         'setpoint.channels'):
        reference_from_params({'setpoint.chanels': ['y']})
