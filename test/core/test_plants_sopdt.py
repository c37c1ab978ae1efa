"""SOPDT plant ([Precup2013] eq. 3.5.8) against closed forms, the exact-delay frequency model and an
independent ODE integration; the kind ``sopdt`` through the plant-kind table."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from support import CONFIG
from support.plant_runs import run

from tank_control.core import params_file
from tank_control.core.analysis.frequency import rational, rational_discrete, ultimate_point
from tank_control.core.interfaces import Plant
from tank_control.core.params import ConfigError
from tank_control.core.plants.kinds.registry import KINDS, get_kind, make_plant
from tank_control.core.plants.sopdt import Sopdt, SopdtConfig
from tank_control.core.scenario import run_in_process


# ------------------------------------------------------------------ independent references
def step_response(times: np.ndarray, gain: float, dead_time: float, case: dict) -> np.ndarray:
    """Unit step response of the continuous SOPDT, textbook closed forms (no code shared)."""
    s = np.maximum(np.asarray(times, dtype=float) - dead_time, 0.0)
    if case['form'] == 'damping':
        big_t, zeta = case['time_constant'], case['damping']
        if big_t == 0.0:
            shape = np.ones_like(s)
        elif zeta == 1.0:
            shape = 1 - (1 + s / big_t) * np.exp(-s / big_t)
        else:
            root = math.sqrt(1 - zeta**2)
            wd = root / big_t
            shape = 1 - np.exp(-zeta * s / big_t) * (np.cos(wd * s) + zeta / root * np.sin(wd * s))
    else:
        t1, t2 = case['time_constant_1'], case['time_constant_2']
        if t1 == 0.0 and t2 == 0.0:
            shape = np.ones_like(s)
        elif t1 == 0.0 or t2 == 0.0:
            shape = 1 - np.exp(-s / max(t1, t2))
        elif t1 == t2:
            shape = 1 - (1 + s / t1) * np.exp(-s / t1)
        else:
            shape = 1 - (t1 * np.exp(-s / t1) - t2 * np.exp(-s / t2)) / (t1 - t2)
    return gain * np.where(np.asarray(times) > dead_time, shape, 0.0)


def denominator(case: dict) -> list[float]:
    """a2·s² + a1·s + 1 from the parameters, highest power first."""
    if case['form'] == 'damping':
        big_t, zeta = case['time_constant'], case['damping']
        return [big_t**2, 2 * zeta * big_t, 1.0]
    return list(np.convolve([case['time_constant_1'], 1.0], [case['time_constant_2'], 1.0]))


DISTINCT = {'form': 'time_constants', 'time_constant_1': 4.0, 'time_constant_2': 1.5}
EQUAL = {'form': 'time_constants', 'time_constant_1': 3.0, 'time_constant_2': 3.0}
UNDERDAMPED = {'form': 'damping', 'time_constant': 2.0, 'damping': 0.3}
CASES = {
    'distinct': DISTINCT,
    'equal': EQUAL,
    'underdamped': UNDERDAMPED,
    'undamped': {'form': 'damping', 'time_constant': 1.2, 'damping': 0.0},
    'critical_by_damping': {'form': 'damping', 'time_constant': 2.5, 'damping': 1.0},
    'first_order': {'form': 'time_constants', 'time_constant_1': 0.0, 'time_constant_2': 2.0},
    'pure_gain': {'form': 'time_constants', 'time_constant_1': 0.0, 'time_constant_2': 0.0},
    'pure_gain_by_damping': {'form': 'damping', 'time_constant': 0.0, 'damping': 0.4},
}


# --------------------------------------------------------------------------------- tests
def test_plant_satisfies_the_protocol_with_channels_y_u_v():
    plant = Sopdt()
    assert isinstance(plant, Plant)
    assert (plant.output_names, plant.input_names, plant.disturbance_names) == (('y',), ('u',),
                                                                               ('v',))


def test_kind_is_in_the_table_and_defaults_are_002s_plant():
    # [Checks] §5: [Ikonen]'s plant G(s) = 2/((s + 1)(0.5 s + 1)), no dead time.
    assert 'sopdt' in KINDS and get_kind('sopdt').config is SopdtConfig
    config = make_plant('sopdt').config
    assert (config.gain, config.form, config.time_constant_1, config.time_constant_2,
            config.dead_time) == (2.0, 'time_constants', 1.0, 0.5, 0.0)


@pytest.mark.parametrize('name', CASES)
@pytest.mark.parametrize('tick', [0.1, 0.37, 1.3])
def test_step_response_at_the_sample_instants_is_the_continuous_one(name, tick):
    # Dead time 2.37 s is not a multiple of any of the ticks (fractional delay).
    case, gain, dead_time, y0, step = CASES[name], -1.7, 2.37, 0.25, 3.0
    plant = Sopdt(SopdtConfig(gain=gain, dead_time=dead_time, output_offset=y0, **case))
    trace = run(plant, lambda t: step, [tick] * int(round(40.0 / tick)))
    expected = y0 + step * step_response(trace[:, 0], gain, dead_time, case)
    # Undamped (ζ = 0, marginally stable): rounding errors do not decay, they add up per step.
    atol = 1e-14 * len(trace) if case.get('damping') == 0.0 else 2e-13
    np.testing.assert_allclose(trace[:, 1], expected, rtol=0, atol=atol)


def test_result_does_not_depend_on_the_step_size():
    def u_of_t(t):
        return 1.0 if t < 6.0 else -0.5       # switches on a common step boundary

    for case in (DISTINCT, EQUAL, UNDERDAMPED):
        config = SopdtConfig(gain=0.8, dead_time=1.9, **case)
        coarse = run(Sopdt(config), u_of_t, [2.0] * 15)
        fine = run(Sopdt(config), u_of_t, [0.125] * 240)
        np.testing.assert_allclose(fine[::16], coarse, rtol=0, atol=1e-14)


def test_near_degenerate_parameters_are_continuous_with_the_degenerate_forms():
    # T1 → T2 and ζ → 1 approach the critically damped response without cancellation.
    times = np.arange(0, 31) * 1.0
    for near, limit in [
        ({'form': 'time_constants', 'time_constant_1': 3.0 * (1 + 1e-9), 'time_constant_2': 3.0},
         EQUAL),
        ({'form': 'damping', 'time_constant': 3.0, 'damping': 1.0 - 1e-12}, EQUAL),
    ]:
        trace = run(Sopdt(SopdtConfig(gain=1.0, **near)), lambda t: 1.0, [1.0] * 30)
        np.testing.assert_allclose(trace[:, 1], step_response(times, 1.0, 0.0, limit),
                                   rtol=0, atol=1e-8)


def test_widely_separated_time_constants_and_long_steps_stay_finite_and_exact():
    case = {'form': 'time_constants', 'time_constant_1': 1e4, 'time_constant_2': 1e-3}
    trace = run(Sopdt(SopdtConfig(gain=1.0, **case)), lambda t: 1.0, [5e3] * 20 + [1e6])
    assert np.all(np.isfinite(trace))
    np.testing.assert_allclose(trace[:, 1], step_response(trace[:, 0], 1.0, 0.0, case),
                               rtol=0, atol=1e-12)


def _pulse_dtft(case: dict, gain: float, dead_time: float, h: float, w: np.ndarray,
                t_end: float) -> np.ndarray:
    """The sampled plant's frequency response: DTFT of its response y(n·h) to u = 1 on [0, h)."""
    plant = Sopdt(SopdtConfig(gain=gain, dead_time=dead_time, **case))
    n_steps = int(round(t_end / h))
    y = run(plant, lambda t: 1.0 if t < h / 2 else 0.0, [h] * n_steps)[:, 1]
    n = np.arange(y.size)
    return np.exp(-1j * np.outer(w, n) * h) @ y


def _zoh_from_continuous(g, h: float, w: np.ndarray, terms: int = 20000) -> np.ndarray:
    """Frequency response of G with ZOH sampled at h (Poisson sum over the aliases):
    (1/h)·Σ_k G(jω_k)·(1 − e^(−jω_k h))/(jω_k), ω_k = ω + 2πk/h."""
    k = np.arange(-terms, terms + 1)
    out = np.empty(w.size, dtype=complex)
    for i, wi in enumerate(w):
        wk = wi + 2 * np.pi * k / h
        out[i] = np.sum(g(wk) * (1 - np.exp(-1j * wk * h)) / (1j * wk)) / h
    return out


@pytest.mark.parametrize('name, dead_time', [('distinct', 1.13), ('equal', 0.0),
                                             ('underdamped', 2.6)])
def test_sampled_frequency_response_is_the_exact_delay_model_with_zoh(name, dead_time):
    case, gain, h = CASES[name], 1.4, 0.25
    w = np.linspace(0.01, np.pi / h * 0.98, 25)
    measured = _pulse_dtft(case, gain, dead_time, h, w, t_end=250.0)
    model = rational([gain], denominator(case), dead_time)
    expected = _zoh_from_continuous(model, h, w)
    np.testing.assert_allclose(measured, expected, rtol=0, atol=1e-12 * gain)
    # The same response as z^(−d)·ZOH(G) when the delay is a whole number of samples.
    if abs(dead_time / h - round(dead_time / h)) < 1e-12:
        numd, dend, _ = signal.cont2discrete(([gain], denominator(case)), h, method='zoh')
        # (rational_discrete's corner estimate takes log of the real negative ZOH zero: silenced)
        with np.errstate(invalid='ignore'):
            zoh = rational_discrete(np.ravel(numd), dend, h, int(round(dead_time / h)))
        np.testing.assert_allclose(measured, zoh(w), rtol=0, atol=1e-10 * gain)


def test_load_disturbance_enters_at_the_plant_input():
    by_u = run(Sopdt(SopdtConfig(dead_time=1.2, **UNDERDAMPED)),
               lambda t: 1.0 if t >= 2.0 else 0.0, [0.5] * 40)
    by_v = run(Sopdt(SopdtConfig(dead_time=1.2, **UNDERDAMPED)), lambda t: 0.0, [0.5] * 40,
               v_of_t=lambda t: 1.0 if t >= 2.0 else 0.0)
    np.testing.assert_array_equal(by_u, by_v)


def _ode_reference(pieces, t_end: float, u_of_t, times: np.ndarray) -> np.ndarray:
    """y at ``times`` by high-accuracy integration of a2·ẍ + a1·ẋ + x = K·u(t − L(t)), with the
    parameters (K, a2, a1, L, y0) of ``pieces`` = [(t_from, params), ...]; x, ẋ continuous."""
    breaks = sorted({0.0, t_end, *(p[0] for p in pieces), *times,
                     *(s + p[1]['L'] for p in pieces for s in (0.0, 4.0, 9.0))})
    breaks = [b for b in breaks if 0.0 <= b <= t_end]

    def params_at(t):
        return [p for t_from, p in pieces if t_from <= t][-1]

    state, out, t_prev = np.zeros(2), {0.0: 0.0}, 0.0
    for t_next in breaks[1:]:
        mid = 0.5 * (t_prev + t_next)
        p = params_at(mid)
        w = u_of_t(mid - p['L'])
        a2, a1, k = p['a2'], p['a1'], p['K']

        def rhs(_t, x):
            return [x[1], (k * w - x[0] - a1 * x[1]) / a2]

        sol = solve_ivp(rhs, (t_prev, t_next), state, method='DOP853', rtol=1e-13, atol=1e-14)
        state = sol.y[:, -1]
        out[t_next] = state[0] + p['y0']
        t_prev = t_next
    return np.array([out[t] for t in times])


def test_live_changes_of_form_time_constants_gain_and_dead_time_act_from_now_on():
    # u switches at 0, 4 and 9 s; at 10 s the form changes to damping and the dead time grows
    # (part of u's history is played back again); at 20 s gain and offset change.
    def u_of_t(t):
        return 0.0 if t < 0.0 else (1.0 if t < 4.0 else (-0.5 if t < 9.0 else 2.0))

    ts = 0.2
    plant = Sopdt(SopdtConfig(gain=0.9, dead_time=1.3, **DISTINCT))
    pieces = [(0.0, {'K': 0.9, 'a2': 6.0, 'a1': 5.5, 'L': 1.3, 'y0': 0.0}),
              (10.0, {'K': 0.9, 'a2': 4.0, 'a1': 0.4, 'L': 2.9, 'y0': 0.0}),
              (20.0, {'K': -0.4, 'a2': 4.0, 'a1': 0.4, 'L': 2.9, 'y0': 1.5})]
    times, ys = [], []
    for k in range(150):
        t = k * ts
        if k == 50:
            y_before, rate_before = plant.outputs()[0], plant.rate
            plant.configure(form='damping', time_constant=2.0, damping=0.1, dead_time=2.9)
            assert (plant.outputs()[0], plant.rate) == (y_before, rate_before)
        if k == 100:
            y_before = plant.outputs()[0]
            plant.configure(gain=-0.4, output_offset=1.5)
            assert plant.outputs()[0] == pytest.approx(y_before + 1.5, abs=1e-15)
        plant.step([u_of_t(t)], [], ts)
        times.append(round((k + 1) * ts, 10))
        ys.append(plant.outputs()[0])
    expected = _ode_reference(pieces, 30.0, u_of_t, np.array(times))
    np.testing.assert_allclose(ys, expected, rtol=0, atol=1e-10)
    assert plant.status['dead_time'] == 2.9


def test_changing_to_a_first_order_form_keeps_the_output_and_follows_it():
    plant = Sopdt(SopdtConfig(gain=1.0, **EQUAL))
    for _ in range(10):
        plant.step([1.0], [], 0.5)
    y = plant.outputs()[0]
    plant.configure(time_constant_1=0.0)          # K/(3 s + 1) from the current output on
    assert plant.outputs()[0] == y
    plant.step([1.0], [], 2.0)
    assert plant.outputs()[0] == pytest.approx(1.0 + (y - 1.0) * math.exp(-2.0 / 3.0), rel=1e-14)


def test_adding_a_lag_to_a_first_order_form_starts_from_its_output_and_slope():
    # K/(2 s + 1) for 5 s of u = 1: y = 1 − e^(−t/2), ẏ = e^(−t/2)/2; then T1 = 3 s is added and
    # (3 s + 1)(2 s + 1) = 6 s² + 5 s + 1 continues from that output and slope.
    plant = Sopdt(SopdtConfig(gain=1.0, form='time_constants', time_constant_1=0.0,
                              time_constant_2=2.0))
    for _ in range(10):
        plant.step([1.0], [], 0.5)
    y5, rate5 = 1 - math.exp(-2.5), math.exp(-2.5) / 2
    assert (plant.outputs()[0], plant.rate) == (pytest.approx(y5, abs=1e-15),
                                                pytest.approx(rate5, abs=1e-15))
    plant.configure(time_constant_1=3.0)
    ys = []
    for _ in range(20):
        plant.step([1.0], [], 0.5)
        ys.append(plant.outputs()[0])
    sol = solve_ivp(lambda _t, x: [x[1], (1.0 - x[0] - 5.0 * x[1]) / 6.0], (5.0, 15.0),
                    [y5, rate5], method='DOP853', rtol=1e-13, atol=1e-14,
                    t_eval=5.0 + 0.5 * np.arange(1, 21))
    np.testing.assert_allclose(ys, sol.y[0], rtol=0, atol=1e-11)


@pytest.mark.parametrize('changes, words', [
    ({'damping': 1.5}, r'damping: 1\.5 is above the maximum; allowed \[0, 1\]'),
    ({'damping': -0.1}, r'damping: -0\.1 is below the minimum'),
    ({'time_constant_1': -1.0}, r'time_constant_1: -1 is below the minimum'),
    ({'time_constant': float('inf')}, 'time_constant: inf is not finite'),
    ({'form': 'critical'},
     "form: 'critical' is not a choice; allowed one of time_constants, damping"),
    ({'gain': float('nan')}, 'gain: nan is not finite'),
    ({'dead_time': 150.0}, 'dead_time: 150 is above max_dead_time; allowed'),
    ({'max_dead_time': 200.0}, 'max_dead_time: read-only'),
    ({'time_constant_3': 1.0}, 'time_constant_3: unknown parameter; did you mean time_constant'),
])
def test_bad_values_are_refused_with_a_reason_and_change_nothing(changes, words):
    plant = Sopdt()
    plant.step([1.0], [], 1.0)
    before = (plant.config, plant.outputs().copy(), plant.rate)
    with pytest.raises(ValueError, match=words):
        plant.configure(output_offset=1.0, time_constant_2=2.0, **changes)
    assert (plant.config, plant.rate) == (before[0], before[2])
    np.testing.assert_array_equal(plant.outputs(), before[1])


@pytest.mark.parametrize('values, words', [
    ({'damping': 2.0}, 'damping: 2 is above the maximum'),
    ({'form': 'underdamped'}, "form: 'underdamped' is not a choice"),
    ({'dead_time': 20.0, 'max_dead_time': 10.0}, 'dead_time: 20 is above max_dead_time'),
])
def test_the_kind_refuses_bad_start_values(values, words):
    with pytest.raises(ConfigError, match=words):
        make_plant('sopdt', values)


def test_reset_returns_to_rest():
    plant = Sopdt(SopdtConfig(output_offset=3.0, dead_time=2.0, **UNDERDAMPED))
    for _ in range(20):
        plant.step([1.0], [], 1.0)
    plant.reset()
    assert (plant.outputs()[0], plant.rate, plant.status['time']) == (3.0, 0.0, 0.0)
    plant.step([0.0], [], 20.0)              # the old input history is gone
    assert plant.outputs()[0] == 3.0


def test_a_scenario_with_plant_sopdt_runs_in_process_through_the_kind_table():
    # [DeadTimeNotes]'s ZN scenario with the plant replaced by K/(T²s² + 2ζTs + 1)·e^(−Ls), K = 0.05,
    # T = 10 s, ζ = 0.7, L = 3 s, and the ZN PID from this plant's ultimate point.
    sections = params_file.read(CONFIG / 'fopdt_zn.yaml')
    sections['plant'].update(plant='sopdt', form='damping', time_constant=10.0, damping=0.7)
    den = [100.0, 14.0, 1.0]
    ku, tu, _ = ultimate_point(rational([0.05], den, 3.0))
    sections['controller'].update({'tuning.ku': ku, 'tuning.tu': tu})
    trace = run_in_process(sections, duration=150.0)
    y, u, r = trace['y.y'], trace['u.u'], trace['r.y']
    assert abs(y[-1] - r[-1]) <= 0.01 * r[-1]
    # The plant's output is the ZOH discretisation of G (scipy) driven by the recorded u,
    # u[k] held on [t_k, t_k+1) and delayed by L = 30 samples.
    ts = sections['plant']['sample_time']
    numd, dend, _ = signal.cont2discrete(([0.05], den), ts, method='zoh')
    delayed = np.concatenate([np.zeros(30), u])[:u.size]
    np.testing.assert_allclose(y, signal.lfilter(np.ravel(numd), dend, delayed), rtol=0,
                               atol=1e-10 * np.max(np.abs(y)))
