"""The harness's outputs from a trace: join of recorded messages, metrics against closed
forms, trace.csv round trip, run.mcap readable by the mcap reader, plot.png."""
from __future__ import annotations

import math

import numpy as np
import pytest
from support.mcap import read_mcap

from tank_control.core.trace import Trace
from tank_control.harness import metrics
from tank_control.harness.recording import write_trace
from tank_control.harness.trace import SignalMessage, from_messages

MS = 1_000_000


def _lockstep_messages(n, ts_ns=100 * MS, skip_manipulated=()):
    out = []
    for k in range(n):
        t = k * ts_ns
        out.append(SignalMessage('measurement', t, ('y',), (0.1 * k,)))
        out.append(SignalMessage('setpoint', t, ('y',), (1.0,)))
        if k not in skip_manipulated:
            out.append(SignalMessage('manipulated', t, ('u',), (2.0 * k,)))
        out.append(SignalMessage('disturbance', t, (), ()))
    return out


def test_join_on_stamps_with_resent_duplicates():
    messages = _lockstep_messages(5)
    messages += messages[:4]                                 # tick 0 re-sent (identical)
    table = from_messages(messages)
    assert list(table.columns) == ['t', 'y.y', 'r.y', 'u.u']
    np.testing.assert_array_equal(table.t, [0.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(table.columns['u.u'], [0, 2, 4, 6, 8])
    assert table.late == {'r': 0, 'u': 0, 'd': 0}


def test_missing_answer_is_counted_late_and_held():
    table = from_messages(_lockstep_messages(4, skip_manipulated=(2,)))
    np.testing.assert_array_equal(table.columns['u.u'], [0, 2, 2, 6])
    assert table.late['u'] == 1


def test_wall_stamps_start_at_first_measurement():
    t0 = 1_700_000_000 * 1_000_000_000
    messages = [SignalMessage('measurement', t0 + k * 50 * MS, ('y',), (k,)) for k in range(3)]
    messages.append(SignalMessage('manipulated', t0 + 60 * MS, ('u',), (5.0,)))
    table = from_messages(messages, t0_ns=t0)
    np.testing.assert_allclose(table.t, [0.0, 0.05, 0.1])
    u = table.columns['u.u']                # held from its own stamp on, NaN before
    assert math.isnan(u[0]) and math.isnan(u[1]) and u[2] == 5.0


def test_wall_row_holds_the_answer_computed_within_its_tick():
    """Row k is what acts over [t_k, t_k+1): the controller's answer sampled in that tick
    (wall mode stamps it when it sampled), which the plant integrates the tick with."""
    t0 = 1_700_000_000 * 1_000_000_000
    messages = [SignalMessage('measurement', t0 + k * 50 * MS, ('y',), (k,)) for k in range(4)]
    messages += [SignalMessage('manipulated', t0 + 60 * MS, ('u',), (5.0,)),
                 SignalMessage('manipulated', t0 + 110 * MS, ('u',), (6.0,))]
    table = from_messages(messages, t0_ns=t0, tick_ns=50 * MS)
    u = table.columns['u.u']
    assert math.isnan(u[0]) and list(u[1:]) == [5.0, 6.0, 6.0]
    assert table.late['u'] == 2            # ticks 0 and 3 had no answer of their own


def test_late_samples_count_due_instants_without_an_answer_and_reported_ones():
    """u due every 2nd tick (controller sample time 0.2 s, plant tick 0.1 s), r and d every
    tick; a due answer is late when missing or when its consumer reported it late."""
    messages = []
    for k in range(8):
        t = k * 100 * MS
        messages.append(SignalMessage('measurement', t, ('y',), (0.0,)))
        if k != 5:
            messages.append(SignalMessage('setpoint', t, ('y',), (1.0,)))
        messages.append(SignalMessage('disturbance', t, ('v',), (0.0,)))
        if k % 2 == 0 and k != 4:
            messages.append(SignalMessage('manipulated', t, ('u',), (float(k),)))
    table = from_messages(messages, tick_ns=100 * MS, due_ns={'u': 200 * MS},
                          late_stamps={'u': [200 * MS, 300 * MS, 400 * MS], 'd': [700 * MS]})
    np.testing.assert_array_equal(table.columns['u.u'], [0, 0, 2, 2, 2, 2, 6, 6])
    # u: instant 0.4 missing, 0.2 reported late (0.3 lies in 0.2's window, 0.4 counts once)
    assert table.late == {'r': 1, 'u': 2, 'd': 1}


def test_lockstep_reference_streams_join_by_zero_order_hold_and_are_late_only_when_never_covered():
    """lockstep: the reference publishes once per change and ahead (``held``): row k takes the
    message in force at t_k, and a due instant is answered by any message stamped at or after
    it; the disturbance here stops at 0.5 s (a dead reference), so 0.6 and 0.7 are late."""
    messages = [SignalMessage('measurement', k * 100 * MS, ('y',), (0.0,)) for k in range(8)]
    messages += [SignalMessage('setpoint', 0, ('y',), (1.0,)),
                 SignalMessage('setpoint', 300 * MS, ('y',), (2.0,)),
                 SignalMessage('setpoint', 900 * MS, ('y',), (2.0,)),      # the hold ahead
                 SignalMessage('disturbance', 0, ('v',), (0.0,)),
                 SignalMessage('disturbance', 500 * MS, ('v',), (0.5,))]
    messages += [SignalMessage('manipulated', k * 100 * MS, ('u',), (1.0,)) for k in range(8)]
    table = from_messages(messages, tick_ns=100 * MS, held=('r', 'd'))
    np.testing.assert_array_equal(table.columns['r.y'], [1, 1, 1, 2, 2, 2, 2, 2])
    np.testing.assert_array_equal(table.columns['d.v'], [0] * 5 + [0.5] * 3)
    assert table.late == {'r': 0, 'u': 0, 'd': 2}
    # the same messages judged per tick (sim, wall): every instant without its own message
    assert from_messages(messages, tick_ns=100 * MS).late == {'r': 6, 'u': 0, 'd': 6}


def test_setpoint_changes_find_steps_ramps_and_an_initial_offset():
    t = np.arange(0, 100.0, 1.0)
    r = np.where(t < 10, 0.0, 1.0)
    r = np.where(t >= 50, np.minimum(1.0 + (t - 50) * 0.25, 3.0), r)   # ramp 1 → 3 over 8 s
    y = np.full_like(t, 0.5)
    changes = metrics.setpoint_changes(t, y, r)
    assert [(c[0], c[3], c[4]) for c in changes] == [(0, 0.5, 0.0), (10, 0.0, 1.0), (51, 1.0, 3.0)]
    assert changes[2][1] == 58                                # constant from the ramp's end


def test_first_order_step_metrics_match_closed_forms():
    tau, dt, delta = 10.0, 0.01, 2.0
    t = np.arange(0.0, 200.0, dt)
    r = np.where(t < 20.0, 1.0, 1.0 + delta)
    y = np.where(t < 20.0, 1.0, 1.0 + delta * (1 - np.exp(-(t - 20.0) / tau)))
    out = metrics.output_metrics(t, y, r)
    (step,) = out['steps']
    assert step['overshoot_pct'] == pytest.approx(0.0, abs=1e-9)
    assert step['rise_time'] == pytest.approx(tau * math.log(9), abs=2 * dt)
    assert step['settling_time'] == pytest.approx(tau * math.log(50), abs=2 * dt)
    assert step['ss_error'] == pytest.approx(0.0, abs=1e-5)
    assert out['iae'] == pytest.approx(delta * tau, rel=1e-3)           # ∫Δe^(−t/τ) dt
    assert out['ise'] == pytest.approx(delta ** 2 * tau / 2, rel=2e-3)  # trapezoid at the jump


def test_second_order_overshoot_matches_closed_form_for_a_downward_step():
    zeta, wn, dt = 0.5, 1.0, 0.001
    t = np.arange(0.0, 40.0, dt)
    wd = wn * math.sqrt(1 - zeta ** 2)
    unit = 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * t))
    y = 5.0 - 3.0 * unit                                       # 5 → 2
    r = np.full_like(t, 2.0)
    r[0] = 5.0
    r[1:] = 2.0
    (step,) = metrics.output_metrics(t, y, r)['steps']
    expected = 100 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta ** 2))
    assert step['overshoot_pct'] == pytest.approx(expected, rel=1e-3)


def test_input_metrics_count_constraint_violations():
    u = np.array([0.0, 5.0, 12.0, -1.0, 3.0])
    m = metrics.input_metrics(u, 0.0, 10.0)
    assert m == {'min': -1.0, 'max': 12.0, 'total_variation': 5 + 7 + 13 + 4,
                 'constraint_violations': 2}


def test_sampling_metrics_count_gaps_and_jitter():
    stamps = np.array([0, 100, 200, 400, 510]) * MS
    m = metrics.sampling_metrics(stamps, 0.1)
    assert m['missed_samples'] == 1
    assert m['max_jitter'] == pytest.approx(0.1)


def _trace():
    t = np.arange(6) * 0.5
    return Trace.ordered({'t': t, 'u.F_H': t * 2, 'y.h': np.sin(t) + 1e-13, 'r.h': np.ones(6),
                    'd.F_D': np.full(6, 12.0)})


def test_trace_csv_round_trip_is_exact_and_ordered(tmp_path):
    trace = _trace()
    assert list(trace.columns) == ['t', 'y.h', 'r.h', 'u.F_H', 'd.F_D']
    again = Trace.read_csv(trace.write_csv(tmp_path / 'trace.csv'))
    for name, column in trace.columns.items():
        np.testing.assert_array_equal(again.columns[name], column)


def test_mcap_from_trace_opens_with_the_mcap_reader(tmp_path):
    trace = _trace()
    seen = read_mcap(write_trace(tmp_path / 'run.mcap', trace))
    assert {'/measurement', '/setpoint', '/manipulated', '/disturbance', '/clock'} <= set(seen)
    h = [m.position[0] for m in seen['/measurement']]
    np.testing.assert_array_equal(h, trace.columns['y.h'])
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in seen['/manipulated']]
    np.testing.assert_allclose(stamps, trace.t)
    assert list(seen['/disturbance'][0].name) == ['F_D']


@pytest.mark.parametrize('names', [(), ('y',), ('h', 'T_out'), ('F_H', 'F_Cin', 'x'),
                                   ('abcd', 'e'), ('T_D', 'F_D', 'long_channel_name')])
def test_the_direct_cdr_encoding_is_the_message_rclpy_reads(names):
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState

    from tank_control.harness.recorder import cdr_stamp_ns, joint_state_from_cdr
    from tank_control.harness.recording import JointStateCdr, clock_cdr
    positions = [math.pi * (i + 1) for i in range(len(names))]
    data = JointStateCdr(names).encode(12, 345_678_901, positions)
    msg = deserialize_message(data, JointState)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 345_678_901)
    assert (tuple(msg.name), list(msg.position)) == (names, positions)
    assert (msg.header.frame_id, list(msg.velocity), list(msg.effort)) == ('', [], [])
    assert joint_state_from_cdr(data) == (12_345_678_901, names, tuple(positions))
    clock = deserialize_message(clock_cdr(7, 9), Clock)
    assert (clock.clock.sec, clock.clock.nanosec) == (7, 9) and cdr_stamp_ns(clock_cdr(7, 9)) == 7e9 + 9


def test_plot_is_a_png(tmp_path):
    from tank_control.harness.plotting import plot_runs
    path = plot_runs([('a', _trace()), ('b', _trace())], tmp_path / 'plot.png', title='x')
    assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_a_disturbance_change_ends_the_setpoint_window_and_is_measured():
    t = np.arange(0.0, 300.0, 0.5)
    r = np.where(t < 10, 0.0, 1.0)
    tau = 5.0
    y = np.where(t < 10, 0.0, 1 - np.exp(-(t - 10) / tau))
    bump = np.where(t >= 150, 0.3 * (t - 150) / 10 * np.exp(-(t - 150) / 10), 0.0)  # peak 0.3/e at 10 s
    y = y - bump
    d = np.where(t < 150, 0.0, -0.1)
    trace = Trace.ordered({'t': t, 'y.y': y, 'r.y': r, 'u.u': np.zeros_like(t), 'd.v': d})
    out = metrics.trace_metrics(trace)['outputs']['y']
    (step,) = out['steps']
    assert step['settling_time'] == pytest.approx(tau * math.log(50), abs=0.5)   # not the load
    (load,) = out['disturbance_steps']
    assert load['t'] == 150.0
    assert load['peak_error'] == pytest.approx(0.3 / math.e, rel=1e-3)
    assert load['peak_time'] == pytest.approx(10.0, abs=0.5)
    assert abs(load['final_error']) < 1e-3


# ------------------------------------------------- events of a multi-output run and their windows

def _bump(t, t0, tau, amp):
    """amp·(s/τ)·e^(1 − s/τ) for s = t − t0 ≥ 0: peak amp at s = τ, ∫ over [0, X·τ] is
    amp·e·τ·(1 − (1 + X)·e^(−X))."""
    s = np.maximum(t - t0, 0.0) / tau
    return amp * s * np.exp(1 - s)


def _bump_integral(amp, tau, length):
    x = length / tau
    return amp * math.e * tau * (1 - (1 + x) * math.exp(-x))


def _bump_recovery(tau, band=0.02):
    """Time after which amp·x·e^(1 − x) stays below band·amp (root x > 1)."""
    from scipy.optimize import brentq
    return tau * brentq(lambda x: x * math.exp(1 - x) - band, 1.0, 50.0)


def _first_order(t, t0, tau, r0, r1):
    return np.where(t < t0, r0, r1 + (r0 - r1) * np.exp(-np.maximum(t - t0, 0.0) / tau))


def _two_output_trace(dt=0.05):
    """Output a: setpoint 0 → 1 at 10 s (first order, τ 5 s); output b: 2 → 3 at 150 s
    (τ 6 s); disturbance v 0 → −0.1 at 300 s; end 400 s. Each event moves the other
    output(s) by a known bump (``_bump``): a's step pushes b down by 0.1 (τ 4 s), b's step
    pushes a up by 0.25 (τ 8 s), the load pushes a down by 0.05 (τ 10 s) and b up by
    0.02 (τ 5 s)."""
    t = np.arange(0.0, 400.0, dt)
    r_a = np.where(t < 10.0, 0.0, 1.0)
    r_b = np.where(t < 150.0, 2.0, 3.0)
    y_a = (_first_order(t, 10.0, 5.0, 0.0, 1.0) + _bump(t, 150.0, 8.0, 0.25)
           - _bump(t, 300.0, 10.0, 0.05))
    y_b = (_first_order(t, 150.0, 6.0, 2.0, 3.0) - _bump(t, 10.0, 4.0, 0.1)
           + _bump(t, 300.0, 5.0, 0.02))
    d = np.where(t < 300.0, 0.0, -0.1)
    return Trace.ordered({'t': t, 'y.a': y_a, 'y.b': y_b, 'r.a': r_a, 'r.b': r_b,
                    'u.u': np.zeros_like(t), 'd.v': d})


def test_a_step_window_ends_at_the_other_outputs_setpoint_change():
    """a's step is measured over 10…150 s, where b's step begins: its overshoot is 0 and
    its settling time τ·ln 50, not the 25 % bump that b's step causes on a afterwards."""
    trace = _two_output_trace()
    m = metrics.trace_metrics(trace)
    assert [(e['t'], e['t_end'], e['kind'], e['channel']) for e in m['events']] == [
        (10.0, 150.0, 'setpoint', 'a'), (150.0, 300.0, 'setpoint', 'b'),
        (300.0, pytest.approx(399.95), 'disturbance', 'v')]
    (step_a,) = m['outputs']['a']['steps']
    assert step_a['t_end'] == 150.0
    assert step_a['overshoot_pct'] == pytest.approx(0.0, abs=1e-9)
    assert step_a['settling_time'] == pytest.approx(5.0 * math.log(50), abs=0.1)
    assert step_a['rise_time'] == pytest.approx(5.0 * math.log(9), abs=0.1)
    (step_b,) = m['outputs']['b']['steps']
    assert step_b['t_end'] == 300.0                                      # ended by the load
    assert step_b['overshoot_pct'] == pytest.approx(0.0, abs=1e-9)
    assert step_b['settling_time'] == pytest.approx(6.0 * math.log(50), abs=0.1)


def test_a_step_reports_the_interaction_on_the_other_output():
    """Peak deviation (signed e = r − y), its time, IAE and recovery of the other output
    over the step's window, against the closed forms of the bumps built into the trace."""
    m = metrics.trace_metrics(_two_output_trace())['outputs']
    (step_a,) = m['a']['steps']
    on_b = step_a['interaction']['b']              # b pushed down 0.1: e_b > 0
    assert set(step_a['interaction']) == {'b'}
    assert on_b['peak_signed'] == pytest.approx(0.1, rel=1e-4)
    assert on_b['peak_error'] == pytest.approx(0.1, rel=1e-4)
    assert on_b['peak_time'] == pytest.approx(4.0, abs=0.05)
    assert on_b['iae'] == pytest.approx(_bump_integral(0.1, 4.0, 140.0), rel=1e-4)
    assert on_b['recovery_time'] == pytest.approx(_bump_recovery(4.0), abs=0.05)
    (step_b,) = m['b']['steps']
    on_a = step_b['interaction']['a']              # a pushed up 0.25: e_a < 0
    assert on_a['peak_signed'] == pytest.approx(-0.25, rel=1e-4)
    assert on_a['peak_time'] == pytest.approx(8.0, abs=0.05)
    assert on_a['iae'] == pytest.approx(_bump_integral(0.25, 8.0, 150.0), rel=1e-4)
    assert on_a['integral_error'] == pytest.approx(-on_a['iae'], rel=1e-9)
    assert on_a['recovery_time'] == pytest.approx(_bump_recovery(8.0), abs=0.05)


def test_a_disturbance_change_is_attributed_within_its_own_window():
    """The load at 300 s pushes a down by 0.05 (e > 0) and b up by 0.02 (e < 0); the larger
    coupling bumps before it are not credited to it."""
    m = metrics.trace_metrics(_two_output_trace())['outputs']
    (load_a,) = m['a']['disturbance_steps']
    (load_b,) = m['b']['disturbance_steps']
    for load in (load_a, load_b):
        assert (load['t'], load['t_end']) == (300.0, pytest.approx(399.95))
        assert load['changes'] == {'v': [0.0, -0.1]}
        assert load['coincident'] == []
    assert load_a['peak_signed'] == pytest.approx(0.05, rel=1e-4)
    assert load_a['peak_time'] == pytest.approx(10.0, abs=0.05)
    assert load_a['iae'] == pytest.approx(_bump_integral(0.05, 10.0, 99.95), rel=1e-4)
    assert load_a['recovery_time'] == pytest.approx(_bump_recovery(10.0), abs=0.05)
    assert load_b['peak_signed'] == pytest.approx(-0.02, rel=1e-4)
    assert load_b['peak_time'] == pytest.approx(5.0, abs=0.05)
    assert load_b['iae'] == pytest.approx(_bump_integral(0.02, 5.0, 99.95), rel=1e-4)


def test_setpoint_changes_below_the_tolerance_are_not_steps():
    """A setpoint written as 33.5714 for an output at 2115/63 = 33.571428… °C (−0.00003 °C)
    is no step at t = 0, and such a change later neither is a step nor ends a window; a
    change of 0.2 % of the magnitude is one."""
    t = np.arange(0.0, 200.0, 1.0)
    t0 = 2115.0 / 63.0
    r = np.where(t < 50, 33.5714, 35.0)
    y = np.full_like(t, t0)
    assert [(c[0], c[3], c[4]) for c in metrics.setpoint_changes(t, y, r)] == [(50, 33.5714, 35.0)]
    small = np.where(t < 120, 33.5714, t0)                 # later −0.00003 … +0.00003 °C
    big = np.where(t < 120, t0, t0 + 0.002 * 35.0)         # 0.2 % of the magnitude
    assert metrics.setpoint_changes(t, y, small) == []
    assert [c[0] for c in metrics.setpoint_changes(t, y, big)] == [120]
    trace = Trace.ordered({'t': t, 'y.h': np.where(t < 10, 81.0, 90.0), 'y.T_out': y,
                     'r.h': np.where(t < 10, 81.0, 90.0), 'r.T_out': small})
    m = metrics.trace_metrics(trace)
    assert [(e['t'], e['t_end']) for e in m['events']] == [(10.0, 199.0)]
    assert m['outputs']['T_out']['steps'] == []


def test_a_ramp_is_one_change_and_a_reversal_starts_another():
    """A reference ramp (several samples moving one way) is one change, as [DeadTimeNotes]'s 25 s ramp
    needs; a setpoint that goes up and straight back down is two."""
    t = np.arange(0.0, 100.0, 1.0)
    ramp = np.clip((t - 10.0) * 4.0, 0.0, 100.0)           # 0 → 100 at 4 /s from 10 s
    assert [c[:2] + c[3:] for c in metrics.setpoint_changes(t, np.zeros_like(t), ramp)] == [
        (11, 35, 0.0, 100.0)]
    pulse = np.where((t >= 40) & (t < 41), 1.0, 0.0)
    assert [(c[0], c[3], c[4]) for c in metrics.setpoint_changes(t, np.zeros_like(t), pulse)] == [
        (40, 0.0, 1.0), (41, 1.0, 0.0)]


def test_simultaneous_events_share_a_window_and_say_so():
    """Steps on both outputs at one instant: each lists the other as coincident and
    reports no interaction on an output that has its own step then."""
    t = np.arange(0.0, 100.0, 1.0)
    r_a, r_b = np.where(t < 20, 0.0, 1.0), np.where(t < 20, 5.0, 4.0)
    d = np.where(t < 20, 0.0, 1.0)
    trace = Trace.ordered({'t': t, 'y.a': r_a, 'y.b': r_b, 'r.a': r_a, 'r.b': r_b, 'd.v': d})
    out = metrics.trace_metrics(trace)['outputs']
    (step_a,) = out['a']['steps']
    assert step_a['interaction'] == {}
    assert step_a['coincident'] == ['r.b', 'd.v']
    assert out['b']['disturbance_steps'][0]['coincident'] == ['r.a', 'r.b']
