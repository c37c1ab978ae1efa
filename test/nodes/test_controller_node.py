"""controller_node over real DDS: parameters, validation, bumpless changes, faults, lockstep.

The test process plays plant and reference through the ``probe`` node. Each
test starts one controller process and runs several checks on it.
"""
from __future__ import annotations

import math
import time

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState

from tank_control.core.interfaces import to_ns
from tank_control.nodes.messages import (ORIGIN_QOS, SIGNAL_QOS, ns_to_stamp, stamp_to_ns,
                                         to_joint_state)

K1 = 0.05      # [Viteckova]'s worked example, [Viteckova] eq. 1


def mdp_pid(k1: float, to: float) -> dict[str, float]:
    """[Viteckova] eqs. 25–26, 32 ([Checks] §3), independent of the tuning module."""
    s3 = math.sqrt(3.0)
    return {'kp': 6 * (2 * s3 - 3) * math.exp(s3 - 3) / (k1 * to), 'ti': (2 + s3) * to,
            'td': (3 + s3) / 18 * to, 'b': (3 - s3) / 3, 'c': (3 - s3) / 2}


class Loop:
    """The probe as plant + reference + operator of one controller node."""

    def __init__(self, probe) -> None:
        self.probe = probe
        node = probe.node
        self.meas = node.create_publisher(JointState, 'measurement', SIGNAL_QOS)
        self.setp = node.create_publisher(JointState, 'setpoint', SIGNAL_QOS)
        self.answers: list[tuple[int, list[str], list[float]]] = []
        self.diag: dict[str, str] = {}
        self.diag_message = ''
        self.diag_level = DiagnosticStatus.OK
        node.create_subscription(JointState, 'manipulated', self._on_u, SIGNAL_QOS)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)
        self.params = AsyncParameterClient(node, 'controller')
        assert self.params.wait_for_services(timeout_sec=30.0), 'controller parameters not up'

    def _on_u(self, msg: JointState) -> None:
        self.answers.append((stamp_to_ns(msg.header.stamp), list(msg.name), list(msg.position)))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith('controller'):
                self.diag = {kv.key: kv.value for kv in status.values}
                self.diag_message = status.message
                self.diag_level = status.level

    def set(self, name: str, value):
        return self.probe.set_once(self.params, name, value)

    def get(self, name: str):
        return Parameter.from_parameter_msg(
            _named(name, self.probe.read(lambda: self.params.get_parameters([name])).values[0])).value

    def tick(self, t_ns: int, y, r, resend_until: float = 30.0):
        """Lockstep tick: send measurement + setpoint stamped t_ns, return u stamped t_ns.
        ``y``, ``r``: a value for channel ``y`` or a {channel: value} map (then the
        answer is a {channel: value} map). Re-sends the tick while unanswered (the
        plant's rule, which also covers discovery)."""
        siso = not isinstance(y, dict)
        ys, rs = ({'y': y}, {'y': r}) if siso else (y, r)

        def answered():
            return any(a[0] == t_ns for a in self.answers)
        waited = 0.0
        while not answered():
            assert waited < resend_until, f'no answer for tick {t_ns}'
            self.meas.publish(to_joint_state(t_ns, list(ys), list(ys.values())))
            self.setp.publish(to_joint_state(t_ns, list(rs), list(rs.values())))
            self.probe.wait_for(answered, 0.5)
            waited += 0.5
        stamp, names, values = next(a for a in self.answers if a[0] == t_ns)
        if siso:
            assert names == ['u']
            return values[0]
        return dict(zip(names, values))


def _named(name, value_msg):
    from rcl_interfaces.msg import Parameter as ParameterMsg
    return ParameterMsg(name=name, value=value_msg)


def _start(procs, node_cmd, ros_env, *params: str):
    argv = node_cmd('controller_node', *[x for p in params for x in ('-p', p)])
    return procs.start('controller', argv, env=ros_env)


def test_before_its_first_sample_diagnostics_report_the_matched_reference_writers(
        procs, node_cmd, ros_env, probe):
    """Before its first sample the controller reports on /diagnostics how many writers the
    middleware has matched to its readers of the reference's signals
    (``matched_writers./setpoint``), soon after a change — not only every
    ``diagnostics_period`` (60 s here): the harness starts the clock once they reach what its
    own graph shows."""
    _start(procs, node_cmd, ros_env, 'clock_mode:=wall', 'diagnostics_period:=60.0',
           'kp:=1.0')
    loop = Loop(probe)        # one writer of setpoint
    assert probe.wait_for(lambda: loop.diag.get('matched_writers./setpoint') == '1', 30), \
        loop.diag
    assert not loop.answers                                  # no sample yet


def test_lockstep_parameters_validation_bumpless_change_and_faults(procs, node_cmd, ros_env, probe):
    ts = 0.2
    # clock_mode auto + use_sim_time (what the harness passes in lockstep) → lockstep answering
    _start(procs, node_cmd, ros_env, 'use_sim_time:=true', f'sample_time:={ts}',
           'diagnostics_period:=0.1',
           'kp:=1.0', 'ti:=10.0', 'b:=0.5', 'u_min:=-5.0', 'u_max:=5.0',
           'initial_output:=[-0.3]')
    loop = Loop(probe)

    # declared with descriptors: range, read-only, description
    described = probe.read(lambda: loop.params.describe_parameters(['kp', 'controller']))
    kp_desc, ctrl_desc = described.descriptors
    assert kp_desc.floating_point_range and kp_desc.floating_point_range[0].from_value == 0.0
    assert 'gain' in kp_desc.description
    assert ctrl_desc.read_only

    tick = to_ns(0.1)     # plant tick 0.1 s; controller samples every second tick
    # tick 0, y = r: the warm start (reset(y, initial_output)) gives u = initial_output
    # exactly, not the cold start's kp·(b·r − y) = −0.5 ([Viteckova] eq. 19 with I = 0)
    assert loop.tick(0, 1.0, 1.0) == pytest.approx(-0.3, abs=1e-12)
    # idempotent: tick 0 re-sent with another measurement gets the same answer again
    before = len(loop.answers)
    loop.meas.publish(to_joint_state(0, ['y'], [4.0]))
    assert probe.wait_for(lambda: len(loop.answers) > before, 20.0)
    assert loop.answers[-1][0] == 0 and loop.answers[-1][2] == [pytest.approx(-0.3, abs=1e-12)]
    # tick 1 is not a controller instant: held even though y changed
    assert loop.tick(1 * tick, 3.0, 1.0) == pytest.approx(-0.3, abs=1e-12)

    # rejected changes: reason names the parameter; the running controller is untouched
    result = loop.set('kp', -1.0)
    assert not result.successful and 'kp' in result.reason
    result = loop.set('u_min', 6.0)
    assert not result.successful and 'u_min' in result.reason and 'u_max' in result.reason
    result = loop.set('n', 100.0)
    assert not result.successful and 'n' in result.reason and '50' in result.reason
    result = loop.set('kpp', 1.0)                 # a misspelt name: refused, nearest suggested
    assert not result.successful and result.reason == 'kpp: unknown parameter; did you mean kp?'
    assert not loop.set('controller', 'smith_pi').successful
    assert loop.get('kp') == 1.0 and loop.get('u_min') == -5.0
    assert loop.tick(2 * tick, 1.0, 1.0) == pytest.approx(-0.3, abs=1e-12)

    # a valid change typed as an integer (ros2 param set /controller kp 3) is accepted
    result = loop.set('kp', 3)
    assert result.successful, result.reason
    assert loop.get('kp') == 3.0
    # applied at the next sample without a bump (a recomputation would give 3·(0.5 − 1) + 0.2)
    assert loop.tick(4 * tick, 1.0, 1.0) == pytest.approx(-0.3, abs=1e-12)
    # and in effect: a measurement step of 0.1 moves u by −kp_new·0.1 (P part)
    u6 = loop.tick(6 * tick, 1.1, 1.0)
    assert u6 == pytest.approx(-0.3 - 3.0 * 0.1, abs=1e-12)

    # non-finite measurement: last output held, counted; recovery without a jump
    assert loop.tick(8 * tick, math.nan, 1.0) == u6
    assert loop.tick(10 * tick, 1.1, 1.0) == pytest.approx(u6, abs=1e-12)
    # fail-safe output on a fault when configured
    assert loop.set('fail_safe_output', 2.0).successful
    assert loop.set('fail_safe', 'output').successful
    assert loop.tick(12 * tick, math.inf, 1.0) == 2.0
    assert probe.wait_for(lambda: int(loop.diag.get('nonfinite_measurements', 0)) >= 2, 20.0)
    assert int(loop.diag['rejected_parameters']) >= 5
    for key in ('mode', 'saturated', 'anti_windup_active', 'stale_inputs', 'rejected_inputs',
                'last_computation_time_us'):
        assert key in loop.diag
    assert float(loop.diag['last_computation_time_us']) > 0.0
    assert loop.tick(14 * tick, 1.1, 1.0) == pytest.approx(2.0, abs=1e-12)   # resumes from 2.0

    # manual mode: switching keeps the current output (manual_output follows it), then
    # the operator's value; back to auto continues from the manual output
    assert loop.set('mode', 'manual').successful
    assert loop.get('manual_output') == pytest.approx(2.0, abs=1e-12)
    assert loop.tick(16 * tick, 1.1, 1.0) == pytest.approx(2.0, abs=1e-12)
    assert loop.set('manual_output', 1).successful
    assert loop.tick(18 * tick, 1.1, 1.0) == 1.0
    assert not loop.set('manual_output', 9.0).successful      # outside [u_min, u_max]
    assert loop.set('mode', 'auto').successful
    assert loop.tick(20 * tick, 1.1, 1.0) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize('trigger', ['measurement', 'timer'])
def test_wall_mode_tuning_rule_and_stale_measurement(procs, node_cmd, ros_env, probe, trigger):
    """Both wall triggers: samples while measurements flow (on their arrival, or on the
    timer), fail-safe output once they stop for stale_samples, bumpless recovery."""
    ts = 0.05
    _start(procs, node_cmd, ros_env, f'sample_time:={ts}', f'trigger:={trigger}', 'tuning.rule:=mdp',
           'tuning.kind:=pid', f'tuning.gain:={K1}', 'tuning.dead_time:=5.0',
           'diagnostics_period:=0.1', 'u_min:=-100.0', 'u_max:=100.0')
    loop = Loop(probe)

    # the rule's gains are applied and visible as parameters ([Viteckova] Table 1: 3.14 / 18.66 / ...)
    for name, value in mdp_pid(K1, 5.0).items():
        assert loop.get(name) == pytest.approx(value, rel=1e-9)
    assert loop.set('tuning.dead_time', 6.0).successful
    assert loop.get('kp') == pytest.approx(mdp_pid(K1, 6.0)['kp'], rel=1e-9)
    result = loop.set('kp', 2.0)
    assert not result.successful and 'tuning.rule' in result.reason

    # measurements flowing: the controller samples on its wall timer
    sending = {'y': True}

    def publish():
        now = probe.node.get_clock().now().nanoseconds
        if sending['y']:
            loop.meas.publish(to_joint_state(now, ['y'], [1.0]))
        loop.setp.publish(to_joint_state(now, ['y'], [1.0]))
    probe.node.create_timer(ts / 2, publish)
    # No sample before the plant's time origin is known (the loop time is plant time) ...
    assert probe.wait_for(lambda: loop.diag_message == "waiting for the plant's time_origin",
                          20.0), loop.diag_message
    assert loop.answers == []
    # ... then every sample_time, once the probe (the plant) has published it (latched).
    probe.node.create_publisher(Time, 'time_origin', ORIGIN_QOS).publish(
        ns_to_stamp(probe.node.get_clock().now().nanoseconds))
    assert probe.wait_for(lambda: len(loop.answers) >= 5, 10.0)
    assert probe.wait_for(lambda: loop.diag.get('fault') == 'none', 20.0)
    assert loop.diag['trigger'] == trigger

    u_running = loop.answers[-1][2][0]
    # stale: no measurement for 3 samples → fail_safe_output sent (configured), reported
    assert loop.set('fail_safe_output', 5.0).successful
    assert loop.set('fail_safe', 'output').successful
    sending['y'] = False
    assert probe.wait_for(lambda: loop.diag.get('fault') == 'stale', 20.0)
    assert loop.diag['stale_inputs'] == 'True'
    n = len(loop.answers)
    assert probe.wait_for(lambda: len(loop.answers) >= n + 3, 20.0)
    assert [a[2][0] for a in loop.answers[n:]] == [5.0] * len(loop.answers[n:])
    assert u_running != 5.0

    # recovery: control resumes from the output the plant got (5.0), no jump; with
    # y = r the error is zero, so it stays there
    sending['y'] = True
    assert probe.wait_for(lambda: loop.diag.get('fault') == 'none', 20.0)
    m = len(loop.answers)
    assert probe.wait_for(lambda: len(loop.answers) >= m + 2, 20.0)
    assert [a[2][0] for a in loop.answers[m:]] == pytest.approx([5.0] * len(loop.answers[m:]),
                                                                abs=1e-9)
    assert int(loop.diag['stale_samples']) >= 3


def test_sim_mode_samples_on_the_simulated_clock_grid(procs, node_cmd, ros_env, probe):
    from rosgraph_msgs.msg import Clock

    from tank_control.nodes.messages import CLOCK_QOS, clock_msg
    ts = 0.5
    _start(procs, node_cmd, ros_env, 'clock_mode:=sim', 'use_sim_time:=true',
           f'sample_time:={ts}', 'kp:=2.0', 'initial_output:=[4.0]')
    loop = Loop(probe)
    clock = probe.node.create_publisher(Clock, '/clock', CLOCK_QOS)
    t = {'ns': 0}

    def advance():
        # The simulated clock moves in steps of 0.35 s, so the 0.5 s timer runs late by
        # 0.2, 0.05, 0.25, 0.1, ... s — as it does on a loaded machine, where /clock
        # messages queue up before the executor gets to the timer.
        t['ns'] += to_ns(0.35)
        loop.meas.publish(to_joint_state(t['ns'], ['y'], [1.0]))
        loop.setp.publish(to_joint_state(t['ns'], ['y'], [3.0]))
        clock.publish(clock_msg(t['ns']))
    probe.node.create_timer(0.01, advance)
    assert probe.wait_for(lambda: len(loop.answers) >= 8, 20.0)
    stamps = [a[0] for a in loop.answers]
    assert all(s % to_ns(ts) == 0 for s in stamps)            # on the k·ts grid
    assert all(b > a for a, b in zip(stamps, stamps[1:])), stamps   # one sample per instant
    # P only; the warm start's bias initial_output − kp·e is 0 here, so u = kp·e
    assert loop.answers[-1][2][0] == pytest.approx(2.0 * (3.0 - 1.0), abs=1e-12)


def test_sim_mode_reports_a_setpoint_that_came_after_its_sample(procs, node_cmd, ros_env,
                                                                 probe):
    """The setpoint of t_k is sent only after the controller answered t_k: it came too
    late for that sample, which used the previous one; both go on ~/late_inputs."""
    from rosgraph_msgs.msg import Clock

    from tank_control.nodes.messages import CLOCK_QOS, clock_msg, from_joint_state
    ts_ns = to_ns(0.5)
    _start(procs, node_cmd, ros_env, 'clock_mode:=sim', 'use_sim_time:=true',
           'sample_time:=0.5', 'diagnostics_period:=0.1')
    loop = Loop(probe)
    clock = probe.node.create_publisher(Clock, '/clock', CLOCK_QOS)
    late: list[tuple[int, tuple, tuple]] = []
    probe.node.create_subscription(JointState, '/controller/late_inputs',
                                   lambda m: late.append(from_joint_state(m)), SIGNAL_QOS)

    def sample(k: int) -> bool:
        """Measurement and /clock of t_k; True once the controller answered t_k."""
        loop.meas.publish(to_joint_state(k * ts_ns, ['y'], [0.0]))
        clock.publish(clock_msg(k * ts_ns))
        return probe.wait_for(lambda: any(a[0] == k * ts_ns for a in loop.answers), 5.0)
    # Start: the first setpoint (stamped 0) and ticks until discovery lets an answer through.
    k0 = 1
    while not loop.answers:
        assert k0 < 60, loop.diag_message
        loop.setp.publish(to_joint_state(0, ['y'], [10.0]))
        probe.wait_for(lambda: bool(loop.answers), 0.5)
        sample(k0)
        k0 += 1
    k0 = loop.answers[-1][0] // ts_ns

    def reported():           # (a re-sent start-up setpoint may be reported late too)
        return [r for r in late if r[0] > k0 * ts_ns]
    for k in range(k0 + 1, k0 + 5):
        assert sample(k), loop.diag_message
        loop.setp.publish(to_joint_state(k * ts_ns, ['y'], [10.0 + k]))    # after the sample
        sample_used = 10.0 + k - 1 if k > k0 + 1 else 10.0
        assert probe.wait_for(lambda: len(reported()) == k - k0, 20.0), late
        assert reported()[-1] == (k * ts_ns, ('y',), (sample_used,))
    assert probe.wait_for(lambda: int(loop.diag.get('late_setpoints', 0)) >= 4, 20.0), loop.diag


def test_two_loop_pi_on_tank_channels_in_lockstep(procs, node_cmd, ros_env, probe):
    _start(procs, node_cmd, ros_env, 'controller:=two_loop_pi', 'clock_mode:=lockstep')
    loop = Loop(probe)
    y, r = {'h': 80.0, 'T_out': 34.0, 'extra': 1.0}, {'h': 81.0, 'T_out': 33.57}
    u = loop.tick(0, y, r)
    # warm start: the first sample takes over at initial_output (default: [Michalski2021]'s operating-point
    # flows 14, 37 cm³/s) whatever the error (a cold start gave kp·e = 0.9, 0.086)
    assert u == pytest.approx({'F_H': 14.0, 'F_Cin': 37.0}, abs=1e-12)
    result = loop.set('two_loop.kp_h', 2)
    assert result.successful, result.reason
    assert not loop.set('u_max', -1.0).successful
    # the change takes effect at this sample without a jump: still the old law's
    # output (integral of tick 0 added, ki·h·e), the new kp_h from the next sample
    u1 = loop.tick(to_ns(1.0), y, r)
    assert u1['F_H'] == pytest.approx(14.0 + 0.01 * 1.0, abs=1e-12)
    # h error 1 → 1.5: u moves by kp_new·0.5 plus the integral of tick 1 (ki·h·1)
    u2 = loop.tick(to_ns(2.0), {**y, 'h': 79.5}, r)
    assert u2['F_H'] == pytest.approx(u1['F_H'] + 2.0 * 0.5 + 0.01 * 1.0, abs=1e-12)


def test_bad_start_up_parameter_exits_with_a_reason(procs, node_cmd, ros_env, probe):
    proc = _start(procs, node_cmd, ros_env, 'kp:=-1.0')
    assert probe.wait_for(lambda: proc.returncode is not None, 20.0)
    assert proc.returncode == 2
    assert 'kp' in proc.tail(5) and 'minimum' in proc.tail(5)


def test_an_input_held_at_its_limit_is_reported(procs, node_cmd, ros_env, probe):
    """A setpoint the input cannot reach: after SATURATION_WARN_SAMPLES samples at the limit
    /diagnostics is WARN naming the input; it clears when the input leaves the limit."""
    from tank_control.nodes.controller_node import SATURATION_WARN_SAMPLES
    # the loop monitor (its own verdict on the last monitor.window) assesses only the last
    # 2 s here, so that its "saturated" verdict ends with the saturation too
    _start(procs, node_cmd, ros_env, 'clock_mode:=lockstep', 'kp:=1.0', 'ti:=1000.0',
           'u_max:=1.0', 'monitor.window:=2.0', 'monitor.period:=1.0')
    loop = Loop(probe)
    tick = to_ns(1.0)                                  # the default sample_time
    assert loop.tick(0, 0.0, 0.0) == 0.0               # the take-over at initial_output
    for k in range(1, SATURATION_WARN_SAMPLES + 2):    # setpoint step 10: kp·10 limited to 1
        assert loop.tick(k * tick, 0.0, 10.0) == 1.0
    assert probe.wait_for(lambda: 'at their limits' in loop.diag_message, 20.0), loop.diag_message
    assert loop.diag_level == DiagnosticStatus.WARN
    assert 'input(s) u at their limits' in loop.diag_message
    assert int(loop.diag['saturated_samples']) >= SATURATION_WARN_SAMPLES
    assert loop.diag['saturated'] == 'True'
    assert 'loop y: saturated' in loop.diag_message      # the monitor's verdict too
    k = SATURATION_WARN_SAMPLES + 2
    assert loop.tick(k * tick, 10.0, 10.0) < 1.0       # error gone: off the limit
    for j in range(k + 1, k + 4):                      # and well inside it (|u| < 0.9)
        assert -0.9 < loop.tick(j * tick, 10.5, 10.0) < 0.9
    assert probe.wait_for(lambda: loop.diag.get('saturated_samples') == '0', 20.0), loop.diag
    assert probe.wait_for(lambda: loop.diag_level == DiagnosticStatus.OK, 20.0), loop.diag_message
    assert 'at their limits' not in loop.diag_message and 'saturated' not in loop.diag_message


def test_use_sim_time_beside_a_wall_clock_plant_is_reported(procs, node_cmd, ros_env, probe):
    """use_sim_time true makes the controller follow plant ticks (lockstep); a plant on the
    wall clock publishes a non-zero time origin and no ticks to answer: ERROR with the remedy
    instead of a silent stop."""
    _start(procs, node_cmd, ros_env, 'use_sim_time:=true')
    loop = Loop(probe)
    origin_pub = probe.node.create_publisher(Time, 'time_origin', ORIGIN_QOS)
    origin_pub.publish(ns_to_stamp(time.time_ns()))          # what a wall plant latches
    assert probe.wait_for(lambda: 'not sampling' in loop.diag_message, 20), loop.diag_message
    assert loop.diag_level == DiagnosticStatus.ERROR
    assert 'the plant runs on the wall clock' in loop.diag_message
    assert 'use_sim_time false' in loop.diag_message


def test_two_loop_pi_gain_table_is_set_or_refused_with_a_reason(procs, node_cmd, ros_env, probe):
    """two_loop.schedule.* over ROS: a bad table is refused naming the parameter and why, the
    feedforward (it decides the topics read) is read-only, a new table takes effect bumplessly
    (the sample of the change still the old law's output, then the new ki_h)."""
    t0 = 2115.0 / 63.0
    _start(procs, node_cmd, ros_env, 'controller:=two_loop_pi', 'clock_mode:=lockstep',
           'two_loop.schedule.variable:=h', 'two_loop.schedule.breakpoints:=[40.0,150.0]',
           'two_loop.schedule.kp_h:=[0.5,2.0]', 'two_loop.schedule.ki_h:=[0.004,0.004]',
           'two_loop.schedule.kp_T:=[-0.05,-0.7]', 'two_loop.schedule.ki_T:=[-0.002,-0.002]')
    loop = Loop(probe)
    y, r = {'h': 80.0, 'T_out': t0}, {'h': 82.0, 'T_out': t0}
    assert loop.tick(0, y, r) == pytest.approx({'F_H': 14.0, 'F_Cin': 37.0}, abs=1e-12)
    u1 = loop.tick(to_ns(1.0), y, r)
    assert u1['F_H'] == pytest.approx(14.0 + 0.004 * 2.0, abs=1e-12)
    refused = loop.set('two_loop.schedule.breakpoints', [150.0, 40.0])
    assert not refused.successful
    assert 'two_loop.schedule.breakpoints' in refused.reason
    assert 'strictly increasing' in refused.reason
    refused = loop.set('two_loop.schedule.kp_h', [1.0])
    assert not refused.successful and 'lengths must be equal' in refused.reason
    refused = loop.set('two_loop.feedforward', 'static')
    assert not refused.successful and 'read-only' in refused.reason
    accepted = loop.set('two_loop.schedule.ki_h', [0.03, 0.03])
    assert accepted.successful, accepted.reason
    assert list(loop.get('two_loop.schedule.ki_h')) == [0.03, 0.03]
    assert list(loop.get('two_loop.schedule.breakpoints')) == [40.0, 150.0]
    u2 = loop.tick(to_ns(2.0), y, r)
    assert u2['F_H'] == pytest.approx(u1['F_H'] + 0.004 * 2.0, abs=1e-12)
    u3 = loop.tick(to_ns(3.0), y, r)
    assert u3['F_H'] == pytest.approx(u2['F_H'] + 0.03 * 2.0, abs=1e-12)


def _wall_loop(procs, node_cmd, ros_env, probe, ts: float):
    """A wall-clock controller (P only, kp 2, b 1: u = 2·(r − y) after the warm start at y = r)
    and the probe as a plant stamping each measurement with the instant of the probe's clock
    (origin + k·ts, as plant_node does), its setpoint r = 1 answered once."""
    proc = _start(procs, node_cmd, ros_env, f'sample_time:={ts}', 'kp:=2.0', 'ti:=0.0',
                  'td:=0.0', 'b:=1.0', 'u_min:=-100.0', 'u_max:=100.0', 'stale_samples:=1000',
                  'diagnostics_period:=0.1')
    loop = Loop(probe)
    clock = probe.node.get_clock()
    origins = probe.node.create_publisher(Time, 'time_origin', ORIGIN_QOS)
    tick = to_ns(ts)
    base = {'origin': clock.now().nanoseconds, 'skew': 0}    # the plant host's clock - ours
    origins.publish(ns_to_stamp(base['origin']))

    def instant() -> int:
        now = clock.now().nanoseconds + base['skew']
        return base['origin'] + (now - base['origin']) // tick * tick

    def measure_until(condition, y: float, timeout: float) -> bool:
        """Measure y at each new instant of the probe's clock until ``condition``."""
        deadline, last = time.monotonic() + timeout, None
        while not condition():
            if time.monotonic() > deadline:
                return False
            if instant() != last:
                last = instant()
                loop.meas.publish(to_joint_state(last, ['y'], [y]))
            probe.wait_for(condition, 0.01)
        return True
    while not loop.answers:       # re-sent until the endpoints match
        loop.setp.publish(to_joint_state(instant(), ['y'], [1.0]))
        measure_until(lambda: bool(loop.answers), 1.0, 0.5)
    return proc, loop, base, origins, instant, measure_until


def test_wall_mode_a_message_stamped_in_the_future_does_not_freeze_the_loop(
        procs, node_cmd, ros_env, probe):
    """One measurement stamped 10 s (and one 1 h) after the plant's latest, and a setpoint
    stamped an hour ahead, are refused (``rejected_future``, /diagnostics WARN): the controller
    keeps sampling each measurement and takes the next valid setpoint. (Before: the 10 s
    measurement was sampled, and no measurement after it was a new instant for 10 s; the
    setpoint froze the setpoint until real time passed its stamp.)"""
    proc, loop, _, _, instant, measure_until = _wall_loop(procs, node_cmd, ros_env, probe,
                                                          ts=0.1)
    latest = loop.answers[-1][0]
    loop.meas.publish(to_joint_state(latest + to_ns(10.0), ['y'], [0.0]))
    loop.meas.publish(to_joint_state(latest + to_ns(3600.0), ['y'], [0.0]))
    loop.setp.publish(to_joint_state(instant() + to_ns(3600.0), ['y'], [50.0]))
    injected = instant()
    # the valid measurements go on being sampled with the valid setpoint: u = 2·(1 − 0.5)

    def after():
        return [a for a in loop.answers if injected < a[0] < injected + to_ns(5.0)]
    assert measure_until(lambda: len(after()) >= 5, 0.5, 30.0), (loop.answers[-3:], proc.tail())
    assert all(a[2][0] == pytest.approx(1.0, abs=1e-12) for a in after()), after()
    # the next valid setpoint is taken: u = 2·(2 − 0.5)
    loop.setp.publish(to_joint_state(instant(), ['y'], [2.0]))
    assert measure_until(lambda: loop.answers[-1][2][0] == pytest.approx(3.0, abs=1e-12), 0.5,
                         30.0), (loop.answers[-3:], proc.tail())
    assert measure_until(lambda: int(loop.diag.get('rejected_future', 0)) == 3, 0.5, 30.0), \
        loop.diag
    assert loop.diag_level == DiagnosticStatus.WARN and 'future' in loop.diag_message
    assert all(a[0] < instant() + to_ns(1.0) for a in loop.answers)   # nothing sent ahead
    assert proc.tail(50).count('ahead of this node') <= 2 * 20   # rate-limited (0.1 s period)


def test_wall_mode_an_unstamped_setpoint_is_refused_counted_and_logged(
        procs, node_cmd, ros_env, probe):
    """README's ``ros2 topic pub`` of a setpoint without a stamp (stamp 0) on a running loop is
    not taken: counted (``rejected_past`` on /diagnostics, WARN) and logged at most once per
    diagnostics period, saying to stamp it (``header: auto``); the setpoint held goes on. The
    same message with ``header: auto`` is taken. (Before: dropped without a trace.)"""
    from support.ros2cli import ros2
    proc, loop, _, _, instant, measure_until = _wall_loop(procs, node_cmd, ros_env, probe,
                                                          ts=0.1)
    pub = ('topic', 'pub', '--once', '/setpoint', 'sensor_msgs/msg/JointState')
    for _ in range(2):
        result = ros2(ros_env, *pub, '{name: [y], position: [50.0]}', '--timeout', '30')
        assert result.returncode == 0, result.stderr
    assert measure_until(lambda: loop.diag.get('rejected_past') == '2', 0.5, 30.0), loop.diag
    assert loop.diag_level == DiagnosticStatus.WARN and 'in the past' in loop.diag_message
    n = len(loop.answers)
    assert measure_until(lambda: len(loop.answers) >= n + 3, 0.5, 30.0)
    # the setpoint held (1) goes on: u = 2·(1 − 0.5)
    assert all(a[2][0] == pytest.approx(1.0, abs=1e-12) for a in loop.answers[n:])
    log = proc.tail(100)
    assert 1 <= log.count('setpoint: message unstamped (stamp 0) refused') <= 2, log
    assert 'header: auto' in log
    result = ros2(ros_env, *pub, '{header: auto, name: [y], position: [2.0]}', '--timeout', '30')
    assert result.returncode == 0, result.stderr
    assert measure_until(lambda: loop.answers[-1][2][0] == pytest.approx(3.0, abs=1e-12), 0.5,
                         30.0), (loop.answers[-3:], proc.tail())
    assert loop.diag.get('rejected_past') == '2'


def test_wall_mode_a_clock_step_is_taken_within_the_documented_bound(
        procs, node_cmd, ros_env, probe):
    """The plant restarts on a host whose clock is an hour ahead (a new time origin, every
    measurement an hour ahead of this controller's clock): both refused at first (an origin
    that far ahead is held back: a stray one would stop the loop, test_hostile_origin.py),
    then the measurements are taken as a clock step — within ``RECOVER_S`` plus a period
    (``core/stamps.py``; a generous margin here for a loaded machine) — and with them the
    origin they are on; the loop runs on."""
    from tank_control.core.stamps import RECOVER_S
    proc, loop, base, origins, _, measure_until = _wall_loop(procs, node_cmd, ros_env,
                                                             probe, ts=0.05)
    base['skew'] = to_ns(3600.0)              # the new session's grid, an hour ahead
    base['origin'] += base['skew']
    origins.publish(ns_to_stamp(base['origin']))
    assert probe.wait_for(lambda: "s ahead of this node's clock refused" in proc.tail(), 20), \
        proc.tail()
    start = time.monotonic()
    assert measure_until(lambda: loop.answers[-1][0] >= base['origin'], 0.5, 30.0), proc.tail()
    took = time.monotonic() - start
    assert RECOVER_S * 0.9 <= took < RECOVER_S + 0.05 + 10.0, took
    n = len(loop.answers)
    assert measure_until(lambda: len(loop.answers) >= n + 5, 0.5, 30.0)   # and runs on
    assert int(loop.diag.get('rejected_future', 0)) >= 3
    assert 'clock step' in proc.tail(50)
    assert f'time_origin {base["origin"]} ns taken' in proc.tail(50)
    # The plant restarts again, now on this host's clock (a new origin, an hour back): the
    # controller answers its measurements at once — not when real time reaches its last
    # output, stamped an hour ahead (before: silent for as long as the step was).
    base['skew'] = 0
    base['origin'] = probe.node.get_clock().now().nanoseconds
    origins.publish(ns_to_stamp(base['origin']))
    assert probe.wait_for(lambda: str(base['origin']) in proc.tail(), 20), proc.tail()
    back = base['origin']
    assert measure_until(lambda: back <= loop.answers[-1][0] < back + to_ns(60.0), 0.5, 30.0), \
        (loop.answers[-3:], proc.tail())
    n = len(loop.answers)
    assert measure_until(lambda: len(loop.answers) >= n + 5, 0.5, 30.0)   # and runs on


@pytest.mark.parametrize('sample_time', [0.1, 0.2])
def test_lockstep_a_measurement_stamped_ahead_of_the_plant_s_tick_does_not_stall_it(
        procs, node_cmd, ros_env, probe, sample_time):
    """lockstep, plant ticks of 0.1 s, the reference's setpoint known 8 ticks ahead: a stray
    measurement stamped two ticks past the latest. With sample_time 0.1 it is more than a
    sample ahead and refused (``rejected_future``); with 0.2 it is within one sample, answered,
    and the plant's re-send of the tick it waits at is answered anew. Either way the plant's
    next tick is answered with its own measurement. (Before: the stray tick was answered and
    the plant's next tick, older, was dropped as a late duplicate every time it was re-sent.)"""
    tick = to_ns(0.1)
    proc = _start(procs, node_cmd, ros_env, 'clock_mode:=lockstep', f'sample_time:={sample_time}',
                  'kp:=2.0', 'ti:=0.0', 'td:=0.0', 'b:=1.0', 'u_min:=-100.0', 'u_max:=100.0',
                  'diagnostics_period:=0.1')
    loop = Loop(probe)
    assert loop.tick(0, 1.0, 1.0) == pytest.approx(0.0, abs=1e-12)
    assert loop.tick(tick, 1.0, 1.0) == pytest.approx(0.0, abs=1e-12)
    loop.setp.publish(to_joint_state(8 * tick, ['y'], [1.0]))        # the reference, ahead
    loop.meas.publish(to_joint_state(3 * tick, ['y'], [-100.0]))     # the stray one
    assert loop.tick(2 * tick, 0.5, 1.0) == pytest.approx(1.0, abs=1e-12), proc.tail()
    # (with 0.2 the stray tick 3 was answered already, the held output: the helper takes that)
    u3 = loop.tick(3 * tick, 0.5, 1.0)
    assert loop.tick(4 * tick, 0.5, 1.0) == pytest.approx(1.0, abs=1e-12), proc.tail()
    assert all(a[2][0] != pytest.approx(202.0) for a in loop.answers)   # y = -100 never used
    if sample_time == 0.1:
        assert u3 == pytest.approx(1.0, abs=1e-12)
        assert probe.wait_for(lambda: loop.diag.get('rejected_future') == '1', 20), \
            (loop.diag.get('rejected_future'), proc.tail())
    else:
        assert 're-sent after' in proc.tail(50)


def test_unknown_empty_and_non_finite_inputs_are_counted_and_logged_with_a_count(
        procs, node_cmd, ros_env, probe):
    """What the plant counts, the controller counts too (before: dropped silently): unknown
    channels (``unknown_channels``; 300 names: one log line with the count, not one per
    name), a message with none of its channels (``empty_inputs``), non-finite values
    (``nonfinite_values``); a message with more than 256 names is refused whole
    (``rejected_inputs``). The loop goes on."""
    proc, loop, _, _, instant, measure_until = _wall_loop(procs, node_cmd, ros_env, probe,
                                                          ts=0.1)
    names = [f'z{i}' for i in range(200)]
    loop.meas.publish(to_joint_state(instant(), names, [1.0] * len(names)))   # none of its own
    loop.setp.publish(to_joint_state(instant(), ['y', 'w'], [float('nan'), 1.0]))
    big = [f'x{i}' for i in range(10_000)]
    loop.meas.publish(to_joint_state(instant(), big, [1.0] * len(big)))

    def counted():
        d = loop.diag
        return (d.get('unknown_channels') == '201' and d.get('empty_inputs') == '1'
                and d.get('nonfinite_values') == '1' and int(d.get('rejected_inputs', 0)) >= 2)
    assert measure_until(counted, 0.5, 30.0), loop.diag
    n = len(loop.answers)
    assert measure_until(lambda: len(loop.answers) >= n + 3, 0.5, 30.0)   # the loop goes on
    log = proc.tail(100)
    assert log.count("unknown channel(s) 'z0', 'z1', 'z2' and 197 more") == 1, log
    assert 'at most 256' in log
