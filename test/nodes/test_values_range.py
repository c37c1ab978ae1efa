"""Hostile values at the nodes over real DDS: implausible measurements, setpoints and plant
inputs are refused like non-finite ones (``range.*``, core/ranges.py), a parameter that would
make the controller compute a non-finite output is refused, and a controller that computes one
anyway goes to its fail-safe and says so (/diagnostics ERROR, ``controller_faults``)."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind
from tank_control.core.interfaces import to_ns
from tank_control.core.params import param
from tank_control.nodes.messages import SIGNAL_QOS, stamp_to_ns, to_joint_state

from nodes.test_controller_node import Loop, _start   # the probe as plant and reference
from nodes.test_plant_node import Recorder, start_plant

TICK = to_ns(0.1)


def test_implausible_measurements_and_setpoints_are_refused_and_counted(procs, node_cmd,
                                                                         ros_env, probe):
    _start(procs, node_cmd, ros_env, 'use_sim_time:=true', 'sample_time:=0.1',
           'diagnostics_period:=0.1', 'kp:=1.0', 'ti:=10.0', 'u_min:=-5.0', 'u_max:=5.0',
           'initial_output:=[-0.3]')
    loop = Loop(probe)
    described = loop.probe.read(lambda: loop.params.describe_parameters(['range.y'])).descriptors[0]
    assert 'plausible range' in described.description
    assert list(loop.get('range.y')) == [-1e5, 1e5]

    assert loop.tick(0, 1.0, 1.0) == pytest.approx(-0.3, abs=1e-12)
    # the measurement of 1e6 (it drove u to -3.45e7): refused, the output held
    assert loop.tick(1 * TICK, 1e6, 1.0) == pytest.approx(-0.3, abs=1e-12)
    assert probe.wait_for(lambda: int(loop.diag.get('out_of_range_measurements', 0)) == 1, 20)
    assert loop.diag_level == DiagnosticStatus.WARN and 'out-of-range' in loop.diag_message
    assert loop.diag['nonfinite_measurements'] == '0'
    # the next good sample resumes bumplessly from the held output
    assert loop.tick(2 * TICK, 1.0, 1.0) == pytest.approx(-0.3, abs=1e-12)
    # one corrupted sample of 1e300 does not disturb what follows: after it the controller
    # acts as before it (a measurement step of 0.1 moves u by -kp·0.1, then the integral
    # adds -kp·h/ti·0.1 per sample)
    assert loop.tick(3 * TICK, 1e300, 1.0) == pytest.approx(-0.3, abs=1e-12)
    assert loop.tick(4 * TICK, 1.0, 1.0) == pytest.approx(-0.3, abs=1e-12)
    u5 = loop.tick(5 * TICK, 1.1, 1.0)
    assert u5 == pytest.approx(-0.3 - 1.0 * 0.1, abs=1e-12)
    u6 = loop.tick(6 * TICK, 1.1, 1.0)
    assert u6 == pytest.approx(u5 - 1.0 * 0.1 / 10.0 * 0.1, abs=1e-12)
    # a setpoint of 1e6 is ignored (the last valid 1.0 kept: the same integral step) and counted
    u7 = loop.tick(7 * TICK, 1.1, 1e6)
    assert u7 == pytest.approx(u6 - 1.0 * 0.1 / 10.0 * 0.1, abs=1e-12)
    assert probe.wait_for(lambda: int(loop.diag.get('rejected_inputs', 0)) >= 1, 20)

    # the range is a parameter: [min, max] changed atomically; a bad one is refused
    result = loop.set('range.y', [5.0, 1.0])
    assert not result.successful and 'range.y' in result.reason and 'min < max' in result.reason
    assert loop.set('range.y', [-10.0, 10.0]).successful
    assert loop.tick(8 * TICK, 20.0, 1.0) == pytest.approx(u7, abs=1e-12)   # now refused
    assert probe.wait_for(lambda: int(loop.diag.get('out_of_range_measurements', 0)) == 3, 20)


def test_a_parameter_that_breaks_the_controller_is_refused(procs, node_cmd, ros_env, probe):
    _start(procs, node_cmd, ros_env, 'controller:=two_loop_pi', 'use_sim_time:=true',
           'sample_time:=1.0', 'diagnostics_period:=0.1')
    loop = Loop(probe)
    y = {'h': 81.0, 'T_out': 2115 / 63}
    u0 = loop.tick(0, y, y)
    # the value: kp·ki underflows to -0.0 and passed the sign check, then F_Cin = NaN
    result = loop.set('two_loop.kp_T', 5e-324)
    assert not result.successful and 'two_loop.kp_T' in result.reason
    assert loop.get('two_loop.kp_T') == -0.2
    u1 = loop.tick(to_ns(1.0), y, y)
    assert all(math.isfinite(v) for v in u1.values()) and u1 == pytest.approx(u0, abs=1e-9)
    assert loop.set('two_loop.kp_T', -0.3).successful          # a good change still applies
    u2 = loop.tick(to_ns(2.0), {'h': 81.0, 'T_out': 34.0}, y)
    assert all(math.isfinite(v) for v in u2.values())
    assert probe.wait_for(lambda: loop.diag.get('update_errors') == '0', 20)
    assert loop.diag_level == DiagnosticStatus.OK


class _Fragile:
    """u = y, but NaN for y > 100 (a controller that cannot compute there)."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    sample_time = 1.0
    status = {'mode': 'auto'}

    def reset(self, y, u):
        pass

    def step(self, t, y, r, d):
        return np.array([float(y[0]) if y[0] <= 100.0 else math.nan])


@dataclass(frozen=True)
class SampleTime:
    sample_time: float = param(1.0, 'sample time', unit='s', min=0.1, max=10.0, read_only=True)


FRAGILE = ControllerKind(name='fragile', description='u = y; NaN above 100', config=SampleTime,
                         build=lambda settings: _Fragile())


def test_a_non_finite_output_goes_to_the_fail_safe_and_says_so(probe, monkeypatch):
    from tank_control.nodes.controller_node import ControllerNode
    monkeypatch.setitem(registry.KINDS, 'fragile', FRAGILE)
    ctrl = ControllerNode(parameter_overrides=[Parameter('controller', value='fragile'),
                                               Parameter('clock_mode', value='lockstep'),
                                               Parameter('diagnostics_period', value=0.1)])
    probe.executor.add_node(ctrl)
    try:
        meas = probe.node.create_publisher(JointState, 'measurement', SIGNAL_QOS)
        setp = probe.node.create_publisher(JointState, 'setpoint', SIGNAL_QOS)
        answers: dict[int, float] = {}
        diag: list[tuple[int, str, dict]] = []
        probe.node.create_subscription(
            JointState, 'manipulated',
            lambda m: answers.__setitem__(stamp_to_ns(m.header.stamp), m.position[0]),
            SIGNAL_QOS)
        probe.node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: diag.extend((s.level, s.message, {kv.key: kv.value for kv in s.values})
                                  for s in m.status if s.name.startswith('controller')), 10)

        def tick(k, y):
            t_ns = k * 1_000_000_000
            while t_ns not in answers:
                meas.publish(to_joint_state(t_ns, ['y'], [y]))
                setp.publish(to_joint_state(t_ns, ['y'], [0.0]))
                probe.wait_for(lambda: t_ns in answers, 0.5)
            return answers[t_ns]

        assert tick(0, 3.0) == 3.0
        assert tick(1, 500.0) == 3.0                   # NaN computed: the last output held
        assert tick(2, 600.0) == 3.0
        assert probe.wait_for(lambda: diag and diag[-1][2].get('controller_faults') == '2', 20)
        level, message, values = diag[-1]
        assert level == DiagnosticStatus.ERROR and 'controller fault' in message
        assert 'non-finite output' in message and values['fault'] == 'controller'
        assert tick(3, 7.0) == 7.0                     # computes again: resumes
        assert probe.wait_for(lambda: diag and diag[-1][0] == DiagnosticStatus.OK, 20)
    finally:
        probe.executor.remove_node(ctrl)
        ctrl.destroy_node()


def answer_ticks(probe, rec, proc, u_of_tick: dict[int, float], k: int) -> None:
    """Answer the lockstep plant's ticks up to ``k`` with ``u_of_tick`` (default 1.0), each
    when its measurement arrives (tick ``j`` re-sent until answered)."""
    while True:
        assert probe.wait_for(lambda: rec.measurements, 20), proc.tail()
        stamp = rec.measurements[-1][0]
        j = stamp // TICK
        rec.manipulated.publish(to_joint_state(stamp, ['u'], [u_of_tick.get(j, 1.0)]))
        if j >= k:
            return
        probe.wait_for(lambda: rec.measurements[-1][0] > stamp, 1.0)


def test_the_plant_refuses_an_implausible_input_and_keeps_its_state_finite(
        procs, ros_env, node_cmd, probe, tmp_path):
    # IPDT k1 = 1, no dead time, lockstep: the probe answers every tick as the controller
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.1,
                       gain=1.0, dead_time=0.0, clock_mode='lockstep', real_time_factor=0.0,
                       diagnostics_period=0.1,
                       **{'lockstep.wait_for_reference': False, 'lockstep.resend_period': 0.2})
    rec = Recorder(probe)
    u_of_tick = {0: 1.0, 1: -1e308, 2: -1e308, 3: 1.0}

    answer_ticks(probe, rec, proc, u_of_tick, 5)
    assert probe.wait_for(lambda: rec.measurements[-1][0] >= 5 * TICK, 20)
    # the issue's -1e308 (it wrecked the state: y = -5e305) is refused, u = 1 kept: slope 1
    for k in range(6):
        assert rec.y_at(k * TICK) == pytest.approx(0.1 * k, abs=1e-12), k
    assert probe.wait_for(lambda: rec.diagnostics
                          and int(rec.diagnostics[-1].get('out_of_range_inputs', 0)) >= 2, 20)
    assert rec.diagnostics[-1]['level'] == DiagnosticStatus.WARN
    # logged at most once per diagnostics period (0.1 s): the two refusals (ticks 1 and 2) in
    # one period give one line, a busy machine may put them in two
    assert 1 <= proc.tail(50).count("outside range.u") <= 2


def test_the_plant_refuses_an_input_far_outside_its_controllers_limits(
        procs, ros_env, node_cmd, probe, tmp_path):
    """The plant started from a file that also holds its controller's section
    takes the controller's output limits [0, 10], widened by 10 % of the span each side, as
    range.u's default: [-1, 11]. The issue's injected u = 1e6 (in ±1e6 before, it drove the
    IPDT to y ≈ 5000) is refused, the last good input kept."""
    path = tmp_path / 'loop.yaml'
    plant = dict(plant='ipdt', sample_time=0.1, gain=1.0, dead_time=0.0, clock_mode='lockstep',
                 real_time_factor=0.0, diagnostics_period=0.1,
                 **{'lockstep.wait_for_reference': False, 'lockstep.resend_period': 0.2})
    controller = {'controller': 'pid', 'sample_time': 0.1, 'u_min': 0.0, 'u_max': 10.0}
    path.write_text(json.dumps({'plant': {'ros__parameters': plant},
                                'controller': {'ros__parameters': controller}}))
    proc = procs.start('plant', node_cmd('plant_node', '--params-file', str(path)), env=ros_env)
    rec = Recorder(probe)
    u_of_tick = {0: 1.0, 1: 1e6, 2: 12.0, 3: 1.0}

    answer_ticks(probe, rec, proc, u_of_tick, 5)
    assert probe.wait_for(lambda: rec.measurements[-1][0] >= 5 * TICK, 20)
    for k in range(6):                        # u = 1 kept: slope 1
        assert rec.y_at(k * TICK) == pytest.approx(0.1 * k, abs=1e-12), k
    assert probe.wait_for(lambda: rec.diagnostics
                          and int(rec.diagnostics[-1].get('out_of_range_inputs', 0)) >= 2, 20)
    # logged at most once per diagnostics period (0.1 s): the two refusals (ticks 1 and 2) in
    # one period give one line, a busy machine may put them in two
    assert 1 <= proc.tail(50).count('outside range.u [-1, 11]') <= 2
