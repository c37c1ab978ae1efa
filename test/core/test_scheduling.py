"""Gain scheduling of the two-loop PI (core/control/scheduling.py): the table, its checks, the
design helper and bumpless gain changes at run time."""
from __future__ import annotations

import numpy as np
import pytest

from tank_control.core.control.kinds import registry, two_loop_pi
from tank_control.core.control.kinds.base import resolve
from tank_control.core.control.scheduling import (GainSchedule, design_schedule,
                                                  diagonal_channels, interpolate)
from tank_control.core.params import ConfigError

T0 = 2115.0 / 63.0                                    # operating-point temperature [°C] ([Michalski2021] §1)
KIND = two_loop_pi.KIND


def test_interpolation_is_linear_between_breakpoints_and_held_outside():
    bp = (40.0, 80.0, 150.0)
    cols = ((1.0, 3.0, 10.0), (-1.0, -2.0, -4.0))
    assert interpolate(bp, cols, 40.0) == (1.0, -1.0)
    assert interpolate(bp, cols, 60.0) == pytest.approx((2.0, -1.5), abs=1e-15)
    assert interpolate(bp, cols, 80.0) == (3.0, -2.0)
    assert interpolate(bp, cols, 115.0) == pytest.approx((6.5, -3.0), abs=1e-15)
    assert interpolate(bp, cols, 10.0) == (1.0, -1.0)          # below: the first row
    assert interpolate(bp, cols, 500.0) == (10.0, -4.0)        # above: the last row
    assert interpolate((81.0,), ((0.9,),), 3.0) == (0.9,)      # one row: constant gains


def _reason(values: dict) -> str:
    with pytest.raises(ConfigError) as info:
        resolve(KIND, values)
    return str(info.value)


def test_the_table_is_declared_once_and_refused_with_reasons():
    names = {s.name for s in KIND.specs()}
    assert {'two_loop.schedule.variable', 'two_loop.schedule.breakpoints',
            'two_loop.schedule.kp_h', 'two_loop.schedule.ki_h', 'two_loop.schedule.kp_T',
            'two_loop.schedule.ki_T', 'two_loop.feedforward'} <= names
    table = {'two_loop.schedule.variable': 'h',
             'two_loop.schedule.breakpoints': [40.0, 80.0, 150.0],
             'two_loop.schedule.kp_h': [0.5, 0.9, 1.7], 'two_loop.schedule.ki_h': [0.005] * 3,
             'two_loop.schedule.kp_T': [-0.05, -0.2, -0.7],
             'two_loop.schedule.ki_T': [-0.002, -0.0027, -0.0037]}
    settings = resolve(KIND, table)
    assert settings.schedule.breakpoints == (40.0, 80.0, 150.0)
    assert _reason({**table, 'two_loop.schedule.breakpoints': [40.0, 40.0, 150.0]}) == (
        'two_loop.schedule.breakpoints: must be strictly increasing; 40 follows 40')
    assert _reason({**table, 'two_loop.schedule.kp_T': [-0.05, -0.2]}) == (
        'two_loop.schedule.kp_T: 2 values for 3 breakpoints; the lengths must be equal')
    assert _reason({**table, 'two_loop.schedule.ki_h': [0.005, float('nan'), 0.005]}
                   ).startswith('two_loop.schedule.ki_h: ')
    assert _reason({**table, 'two_loop.schedule.ki_T': [-0.002, 0.0027, -0.0037]}) == (
        'two_loop.schedule.ki_T: 0.0027 at breakpoint 1 must have the sign of '
        'two_loop.schedule.kp_T (-0.2)')
    assert _reason({**table, 'two_loop.schedule.kp_h': [0.5, -0.9, 1.7],
                    'two_loop.schedule.ki_h': [0.005, -0.005, 0.005]}).endswith(
        'gains of both signs; the action of the loop must not reverse across the table')
    assert _reason({**table, 'two_loop.schedule.variable': 'pressure'}
                   ).startswith('two_loop.schedule.variable')


def test_design_at_the_operating_point_gives_the_document_s_temperature_gain():
    """The diagonal channels at [Michalski2021]'s point, and the SIMC design on them: the temperature loop
    designed with the level loop closed (sequential) has kp_T = −0.196, [Michalski2021] §2.1's −0.2; the
    open channel's design (−0.72, interaction ignored) is 3.7 times larger ([Michalski2021]'s RGA)."""
    m = diagonal_channels(81.0, T0)
    assert (m.F_H, m.F_C) == pytest.approx((14.0, 37.0))
    assert m.level == pytest.approx((2.0 * 81.0 / 63.0, 4.0 * 0.7 * 81.0 ** 2 / 63.0, 0.5))
    assert m.temperature == pytest.approx(((23.0 - T0) / 63.0, 0.7 * 81.0 ** 2 / 63.0, 300.0))
    assert m.temperature_closed[0] == pytest.approx(-39.0 / 63.0)
    table = design_schedule([(40.0, T0), (81.0, T0), (150.0, T0)], level_tau_c=120.0)
    assert table.variable == 'h' and table.breakpoints == (40.0, 81.0, 150.0)
    assert table.kp_T[1] == pytest.approx(-0.196, abs=5e-4)
    open_design = design_schedule([(81.0, T0)], level_tau_c=120.0, sequential=False)
    assert open_design.kp_T[0] / table.kp_T[1] == pytest.approx((62.0 - 23.0) / (T0 - 23.0))
    # SIMC: kp_T ∝ V ∝ h², kp_h = 2·C·h/(tau_c + L) ∝ h
    assert table.kp_T[2] / table.kp_T[0] == pytest.approx((150.0 / 40.0) ** 2)
    assert table.kp_h[2] / table.kp_h[0] == pytest.approx(150.0 / 40.0)
    assert table.reason() is None


def _controller(**values):
    return registry.make_controller('two_loop_pi', values)


def test_output_is_continuous_across_a_breakpoint_crossing():
    """Scheduled on T_out, the h loop's kp_h jumps 1 → 5 between 30 and 31 °C: as T_out moves
    across at a constant level error, F_H keeps growing by ki_h·h·e_h per sample only (the
    integral absorbs kp·e), while the gains in use do move."""
    ctl = _controller(**{'two_loop.schedule.variable': 'T_out',
                         'two_loop.schedule.breakpoints': [30.0, 31.0],
                         'two_loop.schedule.kp_h': [1.0, 5.0],
                         'two_loop.schedule.ki_h': [0.01, 0.02],
                         'two_loop.schedule.kp_T': [-0.2, -0.2],
                         'two_loop.schedule.ki_T': [-0.002, -0.002]})
    r = np.array([81.0, 30.5])
    ctl.reset(np.array([80.0, 29.0]), np.array([14.0, 37.0]))
    flows, kps = [], []
    for k, temp in enumerate(np.linspace(29.0, 32.0, 61)):
        y = np.array([80.0, temp])
        flows.append(ctl.step(float(k), y, r, np.array([]))[0])
        kps.append(ctl.status['kp_h'])
    assert flows[0] == 14.0
    assert kps[0] == 1.0 and kps[-1] == 5.0 and len(set(kps)) > 10
    ki = np.array([interpolate((30.0, 31.0), ((0.01, 0.02),), t)[0]
                   for t in np.linspace(29.0, 32.0, 61)])
    # sample k adds the integral of sample k-1 (ki at k-1, error 1 cm, h = 1 s)
    np.testing.assert_allclose(np.diff(flows), ki[:-1], rtol=0, atol=1e-12)


def test_a_live_table_change_is_bumpless():
    """A new table while running (rebuild, reset to the last output): the sample of the change
    gives the old law's output, then F_H moves by the new ki_h·h·e_h per sample."""
    values = {'two_loop.schedule.variable': 'h', 'two_loop.schedule.breakpoints': [40.0, 150.0],
              'two_loop.schedule.kp_h': [0.5, 2.0], 'two_loop.schedule.ki_h': [0.004, 0.004],
              'two_loop.schedule.kp_T': [-0.05, -0.7], 'two_loop.schedule.ki_T': [-0.002] * 2}
    ctl = registry.build(KIND, resolve(KIND, values))
    y, r, d = np.array([80.0, T0]), np.array([82.0, T0]), np.array([])
    ctl.reset(y, np.array([14.0, 37.0]))
    u = [ctl.step(float(k), y, r, d) for k in range(5)]
    new = {**values, 'two_loop.schedule.kp_h': [3.0, 6.0], 'two_loop.schedule.ki_h': [0.03, 0.03]}
    ctl, u5 = registry.step_with_changes(KIND, ctl, resolve(KIND, new),
                                         frozenset({'two_loop.schedule.kp_h',
                                                    'two_loop.schedule.ki_h'}), 5.0, y, r, d)
    assert u5[0] == pytest.approx(u[-1][0] + 0.004 * 2.0, abs=1e-12)    # old law, continuous
    u6 = ctl.step(6.0, y, r, d)
    assert u6[0] == pytest.approx(u5[0] + 0.03 * 2.0, abs=1e-12)          # new ki, no kp jump
    assert ctl.status['kp_h'] == pytest.approx(3.0 + 3.0 * 40.0 / 110.0)


def test_schedule_on_a_flow_uses_the_last_applied_flow():
    ctl = _controller(**{'two_loop.schedule.variable': 'F_Cin',
                         'two_loop.schedule.breakpoints': [30.0, 40.0],
                         'two_loop.schedule.kp_h': [1.0, 2.0], 'two_loop.schedule.ki_h': [0.01] * 2,
                         'two_loop.schedule.kp_T': [-0.2] * 2,
                         'two_loop.schedule.ki_T': [-0.002] * 2})
    ctl.reset(np.array([81.0, T0]), np.array([14.0, 35.0]))
    ctl.step(0.0, np.array([81.0, T0]), np.array([81.0, T0]), np.array([]))
    assert ctl.status['schedule.value'] == 35.0 and ctl.status['kp_h'] == 1.5


def test_fixed_gains_without_a_schedule_are_unchanged():
    """variable none: the plain two-loop PI (no scheduler, no status keys of it)."""
    ctl = _controller()
    assert ctl.scheduler is None and ctl.feedforward is None
    assert GainSchedule().active is False
