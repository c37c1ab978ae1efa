"""The harness's outputs from a trace: join of recorded messages, metrics against closed
forms, trace.csv round trip, run.mcap readable by the mcap reader, plot.png."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tank_control.harness import metrics
from tank_control.harness.recording import write_trace
from tank_control.harness.trace import SignalMessage, from_messages, ordered, read_csv

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


def read_mcap(path):
    """topic → decoded messages, with the mcap reader and the ROS 2 decoder."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    seen: dict[str, list] = {}
    with open(path, 'rb') as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append(msg)
    return seen


def _trace():
    t = np.arange(6) * 0.5
    return ordered({'t': t, 'u.F_H': t * 2, 'y.h': np.sin(t) + 1e-13, 'r.h': np.ones(6),
                    'd.F_D': np.full(6, 12.0)})


def test_trace_csv_round_trip_is_exact_and_ordered(tmp_path):
    trace = _trace()
    assert list(trace.columns) == ['t', 'y.h', 'r.h', 'u.F_H', 'd.F_D']
    again = read_csv(trace.write_csv(tmp_path / 'trace.csv'))
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
    trace = ordered({'t': t, 'y.y': y, 'r.y': r, 'u.u': np.zeros_like(t), 'd.v': d})
    out = metrics.trace_metrics(trace)['outputs']['y']
    (step,) = out['steps']
    assert step['settling_time'] == pytest.approx(tau * math.log(50), abs=0.5)   # not the load
    (load,) = out['disturbance_steps']
    assert load['t'] == 150.0
    assert load['peak_error'] == pytest.approx(0.3 / math.e, rel=1e-3)
    assert load['peak_time'] == pytest.approx(10.0, abs=0.5)
    assert abs(load['final_error']) < 1e-3
