"""The controllers on the plant models of core/plants, through the Plant and
Controller protocols: y = plant.outputs(); u = controller.step(t, y, r, d); plant.step(u, d, ts)."""
from __future__ import annotations

import numpy as np

from tank_control.core.analysis.step_metrics import step_metrics
from tank_control.core.control.multiloop import TwoLoopPi, document_config
from tank_control.core.control.pid import PidConfig, PidController
from tank_control.core.plants.kinds.registry import make_plant
from tank_control.tuning import tune


def closed_loop(plant, ctl, t_end, r_fn, d_fn=None, events=None):
    """Sample the plant every controller sample time; ``events``: {k: callable(plant)}."""
    ts = ctl.sample_time
    n_d = len(plant.disturbance_names)
    ys, us = [], []
    ctl.reset(plant.outputs(), np.zeros(len(plant.input_names)) if n_d != 4 else plant.nominal_inputs())
    for k in range(int(round(t_end / ts))):
        if events and k in events:
            events[k](plant)
        t = k * ts
        y = plant.outputs()
        u = ctl.step(t, y, r_fn(t), np.array([]))
        d = d_fn(t) if d_fn else (np.zeros(n_d) if n_d != 4 else np.array([]))
        plant.step(u, d, ts)
        ys.append(y)
        us.append(u)
    return np.arange(len(ys)) * ts, np.array(ys), np.array(us)


def _pid(g, h):
    return PidController(PidConfig(kp=g['kp'], ti=g['ti'], td=g['td'] or 0.0, b=g['b'],
                                   c=g['c'] if g['c'] is not None else 1.0, sample_time=h))


def test_ipdt_mdp_pid_with_dead_time_raised_20_percent_at_runtime():
    """[Viteckova] Figs. 6–7 as an operator would see it: To 5 → 6 s while running, then a setpoint step."""
    g = tune('mdp', 'pid', gain=0.05, dead_time=5.0)
    plant = make_plant('ipdt', {'gain': 0.05, 'dead_time': 5.0})
    events = {1000: lambda p: p.configure(dead_time=6.0)}          # at t = 100 s
    t, y, u = closed_loop(plant, _pid(g, 0.1), 300.0, lambda t: np.array([0.0 if t < 150 else 1.0]),
                          events=events)
    m = step_metrics(t, y[:, 0], 1.0, y0=0.0, t_step=150.0)
    assert m.overshoot <= 20.0 and abs(m.steady_state_error) < 1e-3
    assert np.all(np.isfinite(u))


def test_ipdt_load_step_through_the_plant_disturbance_channel():
    g = tune('mdp', 'pi', gain=0.05, dead_time=5.0)
    plant = make_plant('ipdt', {})
    t, y, u = closed_loop(plant, _pid(g, 0.1), 400.0, lambda t: np.array([0.0]),
                          d_fn=lambda t: np.array([1.0 if t >= 10 else 0.0]))
    assert y[:, 0].max() > 0.3
    assert np.abs(y[t > 300, 0]).max() < 1e-3           # rejected, no sustained oscillation
    assert abs(u[-1, 0] + 1.0) < 1e-3                  # u compensates v


def test_fopdt_zn_pid_step_versus_ramp():
    g = tune('zn_001', 'pid', ku=118.2, tu=11.0)
    g.update(b=1.0, c=1.0)
    runs = {}
    # the first sample completes the bumpless reset(y, u) (it returns u whatever r is), so the
    # setpoint moves from the second sample on
    for name, r_fn in (('step', lambda t: np.array([100.0 if t > 0 else 0.0])),
                       ('ramp', lambda t: np.array([100.0 * min(1.0, t / 25.0)]))):
        plant = make_plant('fopdt', {'gain': 0.05, 'time_constant': 10.0, 'dead_time': 3.0})
        t, y, _ = closed_loop(plant, _pid(g, 0.05), 150.0, r_fn)
        runs[name] = step_metrics(t, y[:, 0], 100.0, y0=0.0).overshoot
    assert 35.0 <= runs['step'] <= 70.0
    assert runs['ramp'] <= 10.0


def test_both_two_loop_variants_on_the_nonlinear_tank():
    """[Michalski2021] §2–3 gains on the MixingTank of core/plants: physical, tracking, coupling as in [Michalski2021]."""
    dev = {}
    for variant in ('none', 'dynamic'):
        plant = make_plant('mixing_tank', {'integration_step': 0.5})
        t0 = plant.outputs()[1]
        t, y, u = closed_loop(plant, TwoLoopPi(document_config(variant)), 2500.0,
                              lambda t: np.array([81.0 if t < 100 else 85.0, t0]))
        st = plant.status
        assert st['overflow_steps'] == 0 and st['empty_steps'] == 0
        assert np.all((u >= 0) & (u <= 300))
        assert abs(y[-1, 0] - 85.0) < 0.3
        dev[variant] = np.abs(y[100:, 1] - t0).max()
    assert dev['none'] > 0.5 and dev['dynamic'] < 0.3 * dev['none']
