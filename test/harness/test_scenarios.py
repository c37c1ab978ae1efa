"""The documents' experiments as shipped scenarios (config/scenarios/, config/), each run through the harness and
its documented claim asserted with tolerances ([Checks] §3–4, [Michalski2021] §2; docs/scenarios.md).

The claims run ``--in-process`` (core/loop.py, the same core objects as the nodes); that a
lockstep run over ROS gives the very same trace is asserted in test_scenarios_ros.py, which
also runs a representative few of these claims over the ROS graph.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from support import CONFIG, SCENARIOS
from support.scenario_runs import cached_runs

from tank_control.harness.runner import RunResult

T0 = 2115.0 / 63.0                     # tank operating-point temperature [°C] ([Michalski2021] §1, [Michalski2021] §1)


@pytest.fixture(scope='module')
def results(tmp_path_factory):
    """Each scenario (with overrides) run once per module, in-process."""
    return cached_runs(tmp_path_factory.mktemp('scenarios'))


def first_step(result: RunResult, output: str = 'y') -> dict:
    return result.metrics['outputs'][output]['steps'][0]


def load_step(result: RunResult, output: str = 'y') -> dict:
    return result.metrics['outputs'][output]['disturbance_steps'][0]


# --------------------------------------------------------------------------------- [Viteckova] (IPDT)

@pytest.mark.parametrize('scenario, limit', [
    ('ipdt_pid', 0.5),            # MDP PID 2-DOF: aperiodic, [Checks] §3: 0.02 %
    ('ipdt_mdp_pi', 0.5),         # MDP PI 2-DOF: aperiodic, [Checks] §3: 0.00 %
    ('ipdt_exp_pid', 5.0),        # experimental PID 2-DOF: "nearly aperiodic"
    ('ipdt_exp_pi', 5.0),         # experimental PI 2-DOF: "nearly aperiodic"
])
def test_000_two_dof_setpoint_response_is_nearly_aperiodic(results, scenario, limit):
    step = first_step(results(scenario))
    assert step['overshoot_pct'] <= limit
    assert step['settling_time'] < 60.0                   # settles well inside the 140 s window
    assert abs(step['ss_error']) < 1e-3


@pytest.mark.parametrize('scenario, low, high', [
    ('ipdt_mdp_pi_1dof', 30.0, 40.0),    # [Checks] §3: 34.6 %
    ('ipdt_mdp_pid_1dof', 30.0, 60.0),   # [Checks] §3: 44.7 % (we measure 45.8 %)
])
def test_000_one_dof_controller_overshoots_a_setpoint_step(results, scenario, low, high):
    """[Viteckova] eq. 9: with b = c = 1 the integral of the setpoint error is 0, so y must overshoot."""
    assert low <= first_step(results(scenario))['overshoot_pct'] <= high


@pytest.mark.parametrize('scenario, rule, kind', [
    ('ipdt_pid', 'mdp', 'pid'), ('ipdt_mdp_pi', 'mdp', 'pi'),
    ('ipdt_exp_pid', 'experimental', 'pid'), ('ipdt_exp_pi', 'experimental', 'pi'),
])
def test_000_load_step_rejected_as_eq_10_predicts(results, scenario, rule, kind):
    """[Viteckova] eq. 10: after an input load step v0 the error integral is −Ti·v0/kp (here
    v0 = −0.1, e = r − y, so ∫e dt = Ti·0.1/kp); the response dies out (no sustained
    oscillation). Gains from the tuning formulas of [Viteckova], computed independently here."""
    k1, to = 0.05, 5.0
    if rule == 'mdp':
        kp = (6 * (2 * math.sqrt(3) - 3) * math.exp(math.sqrt(3) - 3) if kind == 'pid'
              else 2 * (math.sqrt(2) - 1) * math.exp(math.sqrt(2) - 2)) / (k1 * to)
        ti = (2 + math.sqrt(3)) * to if kind == 'pid' else (3 + 2 * math.sqrt(2)) * to
    else:
        kp = 1.0 / (k1 * to) if kind == 'pid' else 0.6 / (k1 * to)
        ti = 3 * to if kind == 'pid' else 4.15 * to
    load = load_step(results(scenario))
    assert load['t'] == pytest.approx(150.0)
    assert load['integral_error'] == pytest.approx(ti * 0.1 / kp, rel=0.01)
    assert abs(load['final_error']) < 0.01 * load['peak_error']


@pytest.mark.parametrize('scenario, overrides', [
    ('ipdt_mdp_pid_deadtime_plus20', ()),
    ('ipdt_mdp_pid_deadtime_minus20', ()),
    ('ipdt_mdp_pi', ('plant.dead_time=6.0',)), ('ipdt_mdp_pi', ('plant.dead_time=4.0',)),
    ('ipdt_exp_pid', ('plant.dead_time=6.0',)), ('ipdt_exp_pid', ('plant.dead_time=4.0',)),
    ('ipdt_exp_pi', ('plant.dead_time=6.0',)), ('ipdt_exp_pi', ('plant.dead_time=4.0',)),
])
def test_000_dead_time_off_by_20_percent_stays_well_behaved(results, scenario, overrides):
    """[Viteckova] Figs. 6–7: with To ±20 % both methods stay "relatively robust": the loop is
    stable (setpoint and load responses settle), overshoot ≤ 20 % (docs/scenarios.md)."""
    result = results(scenario, *overrides)
    step, load = first_step(result), load_step(result)
    assert step['overshoot_pct'] <= 20.0
    assert step['settling_time'] is not None and step['settling_time'] < 120.0
    assert abs(step['ss_error']) < 1e-3
    assert abs(load['final_error']) < 0.01 * load['peak_error']


def test_000_controller_gains_are_those_of_table_1(results):
    """[Viteckova] Table 1 (k1 = 0.05, To = 5): MDP PID 3.14 / 18.66 / 1.32 / 0.42 / 0.63."""
    gains = results('ipdt_pid').metrics['controller']['final_gains']
    assert [round(gains[k], 2) for k in ('kp', 'ti', 'td', 'b', 'c')] == [3.13, 18.66, 1.31, 0.42, 0.63]


# ------------------------------------------------------------------------------- [DeadTimeNotes] (FOPDT)

def test_001_zn_pid_overshoots_a_step_and_a_25_s_ramp_cuts_it(results):
    """[DeadTimeNotes] §1.2.2, Figs. 1.13/1.15: the ZN PID overshoots a step of 100 by "about 40 %";
    ramping the setpoint over 25 s cuts it to "about 3 %". We measure 56.6 % and 8.0 %
    (docs/scenarios.md; test_scenarios_001_forms.py on the gap): the claim asserted is a
    large step overshoot (≥ 30 %), a few % with the ramp (≤ 10 %), at least five times less."""
    step = first_step(results('fopdt_zn'))
    ramp = first_step(results('fopdt_zn_ramp'))
    assert step['overshoot_pct'] >= 30.0
    assert ramp['overshoot_pct'] <= 10.0
    assert ramp['overshoot_pct'] * 5 <= step['overshoot_pct']
    for m in (step, ramp):
        assert abs(m['ss_error']) < 0.1


# ------------------------------------------------------------------- [Ikonen] (transfer function)

def _band_entry(result: RunResult, t_step: float, band: float) -> float:
    """Seconds after ``t_step`` from which y stays within ``band`` of the setpoint 1."""
    t, y = result.trace.t, result.trace.columns['y.y']
    outside = np.nonzero(np.abs(y - 1.0) > band)[0]
    return float(t[outside[-1] + 1] - t_step)


def test_002_pi_meets_the_criteria_and_converges_to_the_continuous_loop(results):
    """[Ikonen] ([Checks] §5), Fig. 11: the PI kp 2, Ti 4.2 s on 4/((s + 1)(s + 2)) meets the
    criteria (overshoot ≤ 5 %, zero final error) and enters the 5 % band after "nearly 6 s".
    The continuous loop, simulated here by scipy, gives the reference; the sampled loop
    approaches it as the sample time shrinks (docs/scenarios.md)."""
    from scipy import signal
    num = np.polymul([2.0 * 4.2, 2.0], [4.0])
    cl = signal.TransferFunction(num, np.polyadd(np.polymul([4.2, 0.0], [1.0, 3.0, 2.0]), num))
    t = np.linspace(0.0, 19.0, 190_001)
    _, y = signal.step(cl, T=t)
    continuous = (y.max() - 1.0) * 100.0
    result = results('tf_002_pi')
    step = first_step(result)
    assert step['overshoot_pct'] <= 5.0 and abs(step['ss_error']) < 0.01
    assert 5.0 <= _band_entry(result, 1.0, 0.05) <= 6.0
    fine = first_step(results('tf_002_pi', 'plant.sample_time=0.001',
                              'controller.sample_time=0.001'))
    assert abs(fine['overshoot_pct'] - continuous) < 0.1
    assert abs(fine['overshoot_pct'] - continuous) < abs(step['overshoot_pct'] - continuous) / 5


# ------------------------------------------------------------------------------ [Precup2013] (FSA)

def _second_order_step(w0: float, xi: float, t: np.ndarray) -> np.ndarray:
    """Unit step response of ω0²/(s² + 2ξω0·s + ω0²) ([Precup2013] eq. 3.6.12), ξ < 1."""
    t = np.maximum(t, 0.0)
    wd = w0 * math.sqrt(1.0 - xi * xi)
    return 1.0 - np.exp(-xi * w0 * t) / math.sqrt(1.0 - xi * xi) * np.sin(wd * t + math.acos(xi))


@pytest.mark.parametrize('scenario, dead_time', [('fopdt_fsa', 10.0), ('foupdt_fsa', 5.0)])
def test_004_fsa_gives_the_designed_response_delayed_by_the_dead_time(results, scenario,
                                                                      dead_time):
    """[Precup2013] §3.6.2: FSA removes the dead time from the characteristic equation, so on the
    matching model — stable 1/(10s + 1)·e^(−10s) or unstable 1/(10s − 1)·e^(−5s) — the
    setpoint response is ω0²/p(s)·e^(−L·s) (ξ 0.7, ω0 0.2 rad/s): overshoot 4.60 %, rise and
    2 % settling times those of p(s) plus L (to a sample), the trace within 0.01 of it; after
    the load step v = −0.2 the integral action removes the error."""
    w0, xi, t_step = 0.2, 0.7, 5.0
    result = results(scenario)
    step = first_step(result)
    t = np.linspace(0.0, 95.0, 950_001)
    designed = _second_order_step(w0, xi, t - dead_time)
    rise = t[np.argmax(designed >= 0.9)] - t[np.argmax(designed >= 0.1)]
    settling = t[np.nonzero(np.abs(designed - 1.0) > 0.02)[0][-1] + 1]
    assert step['overshoot_pct'] == pytest.approx(
        100.0 * math.exp(-math.pi * xi / math.sqrt(1.0 - xi * xi)), abs=0.05)
    assert step['rise_time'] == pytest.approx(rise, abs=0.1)
    assert step['settling_time'] == pytest.approx(settling, abs=0.2)
    trace_t, y = result.trace.t, result.trace.columns['y.y']
    before_load = trace_t < 100.0
    assert np.max(np.abs(y[before_load] - _second_order_step(
        w0, xi, trace_t[before_load] - t_step - dead_time))) < 0.01
    load = load_step(result)
    assert load['peak_error'] > 0.1 and abs(load['final_error']) < 1e-4


@pytest.mark.parametrize('scenario, override', [('fopdt_fsa', 'plant.dead_time=11.0'),
                                                ('foupdt_fsa', 'plant.gain=0.9')])
def test_004_fsa_tolerates_a_ten_percent_model_error(results, scenario, override):
    """The plant 10 % off the model (the FSA's prediction is then wrong): still stable, within
    1 % of the setpoint 90 s after its step and without error 100 s after the load step
    (measured overshoot 14.7 % with L 11 s on the stable plant, 15.9 % with K 0.9 on the
    unstable one)."""
    result = results(scenario, override)
    step = first_step(result)
    assert step['overshoot_pct'] < 20.0 and abs(step['ss_error']) < 0.01
    assert abs(load_step(result)['final_error']) < 1e-3


# -------------------------------------------------------------------------- [Michalski2021] (mixing tank)

def window_max_abs(result: RunResult, column: str, ref: str, start: float, stop: float) -> float:
    t = result.trace.t
    keep = (t >= start) & (t < stop)
    return float(np.max(np.abs(result.trace.columns[column][keep] - result.trace.columns[ref][keep])))


def assert_physical(result: RunResult) -> None:
    h = result.trace.columns['y.h']
    assert np.all(h > 0.0) and np.all(h < 200.0)                      # no emptying, no overflow
    temp = result.trace.columns['y.T_out']
    assert np.all((temp >= 23.0 - 1e-9) & (temp <= 62.0 + 1e-9))       # between T_C and T_H
    for name in ('F_H', 'F_Cin'):
        assert result.metrics['inputs'][name]['constraint_violations'] == 0   # 0 ≤ F ≤ 300


@pytest.mark.parametrize('scenario', ['tank_pi', 'tank_pi_decoupled'])
def test_003_two_loop_pi_follows_the_setpoint_sequence(results, scenario):
    """[Michalski2021] §2.2/§3.2: both variants bring h and T_out towards each new setpoint within the
    2000 s until the next change of either setpoint (each step's window). Without decoupling
    every change is reached to within 5 % of its size by then (measured: ≤ 3.0 %, the T_out
    step at 2100 s) and the level steps settle into 2 %; the decoupled loop, lightly damped
    with the document's gains and the tank's delays (test_tank_decoupling_explained.py),
    still swings there, but
    passes 90 % of each change and ends within 50 % of it (measured ≤ 40 %)."""
    result = results(scenario)
    assert_physical(result)
    for output in ('h', 'T_out'):
        steps = result.metrics['outputs'][output]['steps']
        assert len(steps) == 2
        for step in steps:
            size = abs(step['r_to'] - step['r_from'])
            assert step['t_end'] - step['t'] == 2000.0
            assert step['rise_time'] is not None
            if scenario == 'tank_pi':
                assert abs(step['ss_error']) <= 0.05 * size
                if output == 'h':
                    assert step['settling_time'] is not None
            else:
                assert abs(step['ss_error']) <= 0.5 * size


def test_003_coupling_visible_without_decoupling_and_reduced_by_the_decoupler(results):
    """[Michalski2021] §2: "a change of the setpoint of one output visibly affects the other" — a level
    step moves T_out by degrees while its setpoint is constant; §3: the decoupler has a
    positive effect there (the level step barely moves T_out). Read from each level step's
    ``interaction`` in metrics.json, whose window ends at the next change of any setpoint
    (schedule of tank_pi.yaml: T_out at 2100 s and 6100 s), and checked against the trace."""
    plain, decoupled = results('tank_pi'), results('tank_pi_decoupled')
    coupled, reduced = ([s['interaction']['T_out']['peak_error']
                         for s in run.metrics['outputs']['h']['steps']]
                        for run in (plain, decoupled))
    for result, peaks in ((plain, coupled), (decoupled, reduced)):
        steps = result.metrics['outputs']['h']['steps']
        assert [(s['t'], s['t_end']) for s in steps] == [(100.0, 2100.0), (4100.0, 6100.0)]
        for step, peak in zip(steps, peaks):
            assert peak == window_max_abs(result, 'y.T_out', 'r.T_out', step['t'], step['t_end'])
    for a, b in zip(coupled, reduced):
        assert a > 1.0
        assert b < a / 2


def test_003_disturbance_steps_compensated_and_decoupling_comparable(results):
    """[Michalski2021] §2.4: with F_D steps (±25 %) the deviations are not large (< 10 % of the level,
    < 10 % of the T_C–T_H span) and are compensated; §3.4: with decoupling "comparable;
    some errors smaller, some larger"."""
    plain, decoupled = results('tank_pi_disturbance'), results('tank_pi_decoupled_disturbance')
    assert_physical(plain)
    assert_physical(decoupled)
    smaller = larger = 0
    for output, scale in (('h', 81.0), ('T_out', 62.0 - 23.0)):   # level; T_C-T_H span
        ours = plain.metrics['outputs'][output]['disturbance_steps']
        theirs = decoupled.metrics['outputs'][output]['disturbance_steps']
        assert [s['t'] for s in ours] == [100.0, 2600.0]
        for a, b in zip(ours, theirs):
            assert a['peak_error'] < 0.1 * scale                   # not large: < 10 % of scale
            assert abs(a['final_error']) < 0.05 * a['peak_error']  # compensated
            smaller += b['peak_error'] < a['peak_error']
            larger += b['peak_error'] > a['peak_error']
    assert smaller >= 1 and larger >= 1


def test_003_filling_the_tank_overshoots_in_temperature_less_with_decoupling(results):
    """[Michalski2021] §2.5: filling from a low level, the temperature overshoots significantly (the hot
    loop fills the tank while cold water arrives 180 s late); §3.5: with decoupling it
    copes better. Measured: 219 % vs 161 % of the 10.6 °C change — better, but not the
    "negligible" overshoot of the document (docs/scenarios.md)."""
    plain, decoupled = results('tank_fill_pi'), results('tank_fill_pi_decoupled')
    t_plain, t_dec = first_step(plain, 'T_out'), first_step(decoupled, 'T_out')
    assert t_plain['overshoot_pct'] > 50.0
    assert t_dec['overshoot_pct'] < t_plain['overshoot_pct']
    for result in (plain, decoupled):
        assert abs(result.trace.columns['y.h'][-1] - 81.0) < 1.0     # filled to the setpoint
        assert abs(result.trace.columns['y.T_out'][-1] - T0) < 0.1


def _tank_files_at_the_operating_point() -> list[Path]:
    """Shipped files with the mixing tank that start at its operating point (no initial_T)."""
    from tank_control.core.params_file import read as read_params_file
    files = []
    for path in sorted(CONFIG.glob('*.yaml')) + sorted(SCENARIOS.glob('*.yaml')):
        plant = read_params_file(path).get('plant', {})
        if plant.get('plant') in ('mixing_tank', 'mixing_tank_linear') and 'initial_T' not in plant:
            files.append(path)
    return files


@pytest.mark.parametrize('path', _tank_files_at_the_operating_point(), ids=lambda p: p.stem)
def test_003_tank_files_start_the_temperature_setpoint_exactly_at_the_operating_point(path):
    """Such a file sets T_out's first setpoint to 2115/63 itself, not a rounding of it
    (33.5714 made a −0.00003 °C "step")."""
    from tank_control.core.params_file import read as read_params_file
    reference = read_params_file(path)['reference']
    first = reference.get('setpoint.T_out.values', [reference.get('setpoint.T_out.value')])[0]
    assert first == T0


def test_003_unreachable_temperature_setpoint_winds_up_and_raises_the_level(results):
    """[Michalski2021] §2.2: with T_out set near T_C while warm F_D flows in, the temperature error stays
    and the level rises (the cold-water integrator keeps opening F_Cin)."""
    result = results('tank_pi_unreachable')
    (step,) = result.metrics['outputs']['T_out']['steps']
    assert step['r_to'] == 24.0
    assert step['ss_error'] < -0.5                               # T_out stays above 24 °C
    h = result.trace.columns['y.h']
    assert h[-1] > 81.0 + 10.0                                   # level far above its setpoint
    assert result.metrics['inputs']['F_H']['min'] == 0.0         # hot water shut off


def test_003_the_linearised_tank_makes_the_unreachable_setpoint_look_reachable(results):
    """[Michalski2021] §2.3 (Figs. 4–6): on the linearised plant the same loop looks better behaved at
    the extreme setpoint — dangerous, since the tank cannot get there. The linear model's T
    equation reaches 24 °C with F_H = 0 at a cold flow the tank would need twice of."""
    linear, tank = results('tank_pi_linear_extreme'), results('tank_pi_unreachable')
    t_lin, t_tank = (r.trace.columns['y.T_out'] for r in (linear, tank))
    assert t_lin[-1] - 24.0 < 0.5 * (t_tank[-1] - 24.0)          # much closer to 24 °C
    assert t_lin[-1] < t_lin[-1000]                                 # and still approaching
    assert linear.trace.columns['y.h'].max() < tank.trace.columns['y.h'].max()
    assert linear.metrics['inputs']['F_H']['min'] == 0.0            # hot water shut as well
    # Steady mixing balance with F_H = 0: the tank's T = 24 °C needs
    # F_C = F_D·(T_D − 24)/(24 − T_C) = 108 cm³/s. Linearised at the operating point,
    # dT·F_in = Σ (T_i − T0)·dF_i with dF_H = −14 reaches 24 °C at F_C ≈ 56 cm³/s.
    t0, f_in = T0, 63.0
    f_c_linear = 37.0 + ((24.0 - t0) * f_in + 14.0 * (62.0 - t0)) / (23.0 - t0)
    assert f_c_linear < 0.6 * 108.0
    assert linear.trace.columns['u.F_Cin'][-1] == pytest.approx(f_c_linear, rel=0.05)


def test_003_decoupled_loop_on_the_linearised_tank_undershoots_below_t_c(results):
    """[Michalski2021] §3.3 (Figs. 10–12): with decoupling, the linear model is "even more dangerous": it
    lets the temperature fall below T_C = 23 °C, which no mixture of the tank's inflows
    (23, 33 and 62 °C) can produce. The same loop on the tank stays physical (and overflows
    the tank instead: docs/scenarios.md)."""
    linear = results('tank_pi_decoupled_linear_extreme')
    tank = results('tank_pi_decoupled_linear_extreme', 'plant.plant=mixing_tank')
    assert linear.trace.columns['y.T_out'].min() < 23.0 - 5.0
    assert tank.trace.columns['y.T_out'].min() >= 23.0 - 1e-9
    assert tank.trace.columns['y.h'].max() == pytest.approx(200.0)          # at the brim


def test_003_setpoint_guard_keeps_the_level_when_the_temperature_is_unreachable(results):
    """Our answer to that failure mode (the controller's two_loop.setpoint_guard, on by
    default): the same unreachable request leaves the level at its setpoint and T_out at
    the coldest reachable temperature instead of winding up."""
    result = results('tank_pi_unreachable', 'controller.two_loop.setpoint_guard=true')
    assert_physical(result)
    h = result.trace.columns['y.h']
    assert abs(h[-1] - 81.0) < 0.5
    temp = result.trace.columns['y.T_out'][-1]
    assert 24.0 < temp < 27.0                       # as cold as F_D at 33 °C allows, not 24
