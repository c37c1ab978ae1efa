"""IPDT and FOPDT plants against closed forms ([Viteckova] eq. 1, §1.2)."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from scipy.integrate import quad
from support.plant_runs import run

from tank_control.core.interfaces import Plant
from tank_control.core.plants.fopdt import Fopdt, FopdtConfig
from tank_control.core.plants.ipdt import Ipdt, IpdtConfig

NS = 1e-9


def relay_loop(plant, d: float, r: float, dead_time: float, ts: float, t_end: float):
    """Ideal relay u = d·sign(r − y) around ``plant``, with exact switching instants.

    The loop steps by ``ts``; when the error changes sign inside a step the
    crossing instant is bisected to 1 ns on copies of the plant and the relay
    switches there. Every ``crossing + dead_time`` instant is also a step
    boundary, because that is where the extremes of the cycle are.
    Returns (crossing times, instants, outputs).
    """
    u = d
    t_ns, ts_ns, end_ns = 0, round(ts / NS), round(t_end / NS)
    crossings, times, ys = [], [0.0], [plant.outputs()[0]]
    events: list[int] = []
    while t_ns < end_ns:
        step_ns = min(ts_ns, *(e - t_ns for e in events if e > t_ns), end_ns - t_ns)
        trial = copy.deepcopy(plant)
        trial.step([u], [], step_ns * NS)
        if (r - trial.outputs()[0]) * u < 0.0:          # crossed: find the instant
            lo, hi = 0, step_ns
            while hi - lo > 1:
                mid = (lo + hi) // 2
                probe = copy.deepcopy(plant)
                probe.step([u], [], mid * NS)
                lo, hi = (mid, hi) if (r - probe.outputs()[0]) * u >= 0.0 else (lo, mid)
            plant.step([u], [], hi * NS)
            t_ns += hi
            crossings.append(t_ns * NS)
            events.append(t_ns + round(dead_time / NS))
            u = -u
        else:
            plant, t_ns = trial, t_ns + step_ns
        times.append(t_ns * NS)
        ys.append(plant.outputs()[0])
    return np.array(crossings), np.array(times), np.array(ys)


def _cycle_measures(crossings, times, ys, skip_time):
    period = np.diff(crossings[::2])[-2:]
    late = times > skip_time
    amplitude = (ys[late].max() - ys[late].min()) / 2
    centre = (ys[late].max() + ys[late].min()) / 2
    return period, amplitude, centre


def test_plants_satisfy_the_protocol():
    assert isinstance(Ipdt(), Plant) and isinstance(Fopdt(), Plant)
    assert Fopdt().output_names == ('y',) and Fopdt().input_names == ('u',)
    assert Fopdt().disturbance_names == ('v',)


def test_fopdt_relay_limit_cycle_matches_closed_form():
    # [Checks] §1: a = K·d·(1 − e^(−L/T)), P = 2T·ln(2·e^(L/T) − 1); L not a multiple of ts.
    K, T, L, d, y0 = 0.05, 10.0, 2.7183, 1.0, 1.5
    plant = Fopdt(FopdtConfig(gain=K, time_constant=T, dead_time=L, output_offset=y0))
    crossings, times, ys = relay_loop(plant, d, y0, L, ts=0.01, t_end=45.0)
    period, amplitude, centre = _cycle_measures(crossings, times, ys, skip_time=15.0)
    a = K * d * (1 - math.exp(-L / T))
    P = 2 * T * math.log(2 * math.exp(L / T) - 1)
    assert period == pytest.approx([P, P], rel=1e-7)
    assert amplitude == pytest.approx(a, rel=1e-6)
    assert centre == pytest.approx(y0, abs=1e-9)


def test_ipdt_relay_limit_cycle_matches_closed_form():
    # IPDT: y rises for To after each crossing → a = k1·d·To, half period 2·To (P = 4·To = Tu).
    k1, To, d = 0.05, 5.0 + 1.0 / 3.0, 2.0
    plant = Ipdt(IpdtConfig(gain=k1, dead_time=To))
    crossings, times, ys = relay_loop(plant, d, 0.0, To, ts=0.03, t_end=80.0)
    period, amplitude, centre = _cycle_measures(crossings, times, ys, skip_time=20.0)
    assert period == pytest.approx([4 * To, 4 * To], rel=1e-7)
    assert amplitude == pytest.approx(k1 * d * To, rel=1e-6)
    assert centre == pytest.approx(0.0, abs=1e-9)


def test_fopdt_step_response_is_exact_with_a_fractional_dead_time():
    K, T, L, y0, step = 0.05, 10.0, 3.3, -2.0, 4.0
    trace = run(Fopdt(FopdtConfig(gain=K, time_constant=T, dead_time=L, output_offset=y0)),
                 lambda t: step, [0.4] * 100)
    t = trace[:, 0]
    expected = y0 + K * step * np.where(t > L, 1 - np.exp(-(t - L) / T), 0.0)
    np.testing.assert_allclose(trace[:, 1], expected, rtol=0, atol=1e-13)


def test_ipdt_step_response_is_exact_with_a_fractional_dead_time():
    k1, To, y0, step = 0.05, 5.0, 1.0, 3.0
    trace = run(Ipdt(IpdtConfig(gain=k1, dead_time=To, output_offset=y0)),
                 lambda t: step, [0.3] * 60)          # 5 / 0.3 is not an integer
    t = trace[:, 0]
    np.testing.assert_allclose(trace[:, 1], y0 + k1 * step * np.maximum(t - To, 0.0),
                               rtol=0, atol=1e-13)


def test_load_disturbance_enters_at_the_plant_input():
    # y = G·(u + v): a step in v gives the same response as a step in u.
    by_u = run(Fopdt(), lambda t: 1.0 if t >= 2.0 else 0.0, [0.5] * 40)
    by_v = run(Fopdt(), lambda t: 0.0, [0.5] * 40, v_of_t=lambda t: 1.0 if t >= 2.0 else 0.0)
    np.testing.assert_array_equal(by_u, by_v)


def test_result_does_not_depend_on_the_step_size():
    def u_of_t(t):
        return 1.0 if t < 6.0 else -0.5       # switches on a common step boundary

    coarse = run(Fopdt(), u_of_t, [2.0] * 10)
    fine = run(Fopdt(), u_of_t, [0.125] * 160)
    np.testing.assert_allclose(fine[::16], coarse, rtol=0, atol=1e-14)


def _independent_output(gain, T, y0, u_of_t, w_of_t, t_end, points):
    """y(t_end) by adaptive quadrature of the impulse response times w(s)."""
    if T is None:        # IPDT: y = y0 + k1·∫ w
        kernel = lambda s: gain * w_of_t(s)
    else:                # FOPDT: y = y0 + ∫ (K/T)·e^(−(t−s)/T)·w(s) ds
        kernel = lambda s: gain / T * math.exp(-(t_end - s) / T) * w_of_t(s)
    cuts = sorted(p for p in points if 0 < p < t_end)
    edges = [0.0, *cuts, t_end]
    return y0 + sum(quad(kernel, a, b, epsabs=1e-13, epsrel=1e-12)[0]
                    for a, b in zip(edges, edges[1:]) if b > a)


@pytest.mark.parametrize('kind', ['ipdt', 'fopdt'])
def test_runtime_dead_time_change_keeps_history(kind):
    # A pulse on [10, 12); at t = 20 the dead time grows from 3 to 9.4 s, so the
    # pulse is played back once more: w(t) = u(t − L(t)).
    L1, L2, t_change, ts = 3.0, 9.4, 20.0, 0.2

    def u_of_t(t):
        return 2.0 if 10.0 <= t < 12.0 else 0.0

    def w_of_t(s):
        return u_of_t(s - (L1 if s < t_change else L2))

    if kind == 'ipdt':
        plant, gain, T = Ipdt(IpdtConfig(dead_time=L1, output_offset=0.5)), 0.05, None
    else:
        plant, gain, T = Fopdt(FopdtConfig(dead_time=L1, output_offset=0.5)), 0.05, 10.0
    t = 0.0
    for k in range(200):
        if abs(t - t_change) < 1e-9:
            plant.configure(dead_time=L2)
        plant.step([u_of_t(t)], [0.0], ts)
        t = (k + 1) * ts
        if k % 10 == 9:
            points = [10 + L1, 12 + L1, t_change, 10 + L2, 12 + L2]
            expected = _independent_output(gain, T, 0.5, u_of_t, w_of_t, t, points)
            assert plant.outputs()[0] == pytest.approx(expected, abs=1e-10), t
    assert plant.status['dead_time'] == L2


def test_dead_time_change_that_shortens_the_delay_skips_history():
    plant = Ipdt(IpdtConfig(gain=1.0, dead_time=4.0))
    for k in range(10):                     # u = 1 on [0, 10)
        plant.step([1.0], [0.0], 1.0)
    assert plant.outputs()[0] == pytest.approx(6.0)
    plant.configure(dead_time=1.0)          # from t = 10 read u(t − 1): 1 for one second, then 0
    for k in range(5):
        plant.step([0.0], [0.0], 1.0)
    assert plant.outputs()[0] == pytest.approx(7.0)


def test_live_gain_and_offset_changes_act_from_now_on():
    plant = Fopdt(FopdtConfig(gain=1.0, time_constant=2.0, dead_time=0.0))
    for _ in range(50):
        plant.step([1.0], [0.0], 1.0)
    y = plant.outputs()[0]
    plant.configure(gain=3.0, output_offset=10.0)
    assert plant.outputs()[0] == pytest.approx(y + 10.0)
    plant.step([1.0], [0.0], 2.0)
    expected = 10.0 + 3.0 + (y - 3.0) * math.exp(-1.0)
    assert plant.outputs()[0] == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize('changes, words', [
    ({'dead_time': 150.0}, 'dead_time: 150 is above max_dead_time'),
    ({'dead_time': -1.0}, 'dead_time: -1 is below the minimum'),
    ({'time_constant': float('nan')}, 'time_constant: nan is not finite'),
    ({'gain': 'big'}, "gain: 'big' is a str"),
    ({'max_dead_time': 200.0}, 'max_dead_time: read-only'),
    ({'delay': 1.0}, 'delay: unknown parameter'),
])
def test_bad_configuration_is_rejected_with_a_reason_and_changes_nothing(changes, words):
    plant = Fopdt()
    before = plant.config
    with pytest.raises(ValueError, match=words):
        plant.configure(output_offset=1.0, **changes)
    assert plant.config == before


@pytest.mark.parametrize('u, d, dt, words', [
    ([float('nan')], [0.0], 1.0, 'u: non-finite'),
    ([1.0, 2.0], [0.0], 1.0, 'u: 2 values given, expected 1'),
    ([1.0], [float('inf')], 1.0, 'd: non-finite'),
    ([1.0], [0.0], -1.0, 'dt'),
])
def test_bad_step_input_is_rejected_and_never_reaches_the_plant(u, d, dt, words):
    plant = Ipdt()
    plant.step([1.0], [0.0], 10.0)
    state = (plant.outputs().copy(), plant.status)
    with pytest.raises(ValueError, match=words):
        plant.step(u, d, dt)
    np.testing.assert_array_equal(plant.outputs(), state[0])
    assert plant.status == state[1]


def test_reset_returns_to_rest():
    plant = Ipdt(IpdtConfig(output_offset=3.0))
    for _ in range(20):
        plant.step([1.0], [], 1.0)
    plant.reset()
    assert plant.outputs()[0] == 3.0 and plant.status['time'] == 0.0
    plant.step([0.0], [], 20.0)              # the old input history is gone
    assert plant.outputs()[0] == 3.0
