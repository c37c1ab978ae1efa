"""reference_node over real DDS: its parameters always equal the schedule it runs, and the
schedule lists change together (one set_parameters call with several parameters, as
``ros2 param load`` sends, is one atomic change).

The probe plays the plant (``/clock`` ticks, lockstep) and reads the parameters back after
every change, comparing the schedule they describe with the setpoints published from then on.
"""
from __future__ import annotations

import json

from rcl_interfaces.msg import Parameter as ParameterMsg
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from support.ros2cli import ros2

from tank_control.core.reference import ChannelSchedule
from tank_control.harness.recorder import RECORD_QOS
from tank_control.nodes.messages import CLOCK_QOS, clock_msg, from_joint_state

TS = 100_000_000        # tick [ns]
FIELDS = ('times', 'values', 'ramp_rate', 'min', 'max')


class Reference:
    """The probe as the plant (clock) and operator of one reference_node."""

    def __init__(self, probe) -> None:
        self.probe = probe
        self.setpoints: list[tuple[int, float]] = []
        probe.node.create_subscription(
            JointState, 'setpoint',
            lambda m: self.setpoints.append((from_joint_state(m)[0], from_joint_state(m)[2][0])),
            RECORD_QOS)
        self.clock = probe.node.create_publisher(Clock, '/clock', CLOCK_QOS)
        self.client = AsyncParameterClient(probe.node, 'reference')
        assert self.client.wait_for_services(timeout_sec=30.0), 'reference parameters not up'
        self.k = -1

    def tick(self, ticks: int = 1) -> None:
        """The next ``ticks`` plant ticks, each until answered: until the setpoint is known
        through the tick after it (lockstep: published ahead under zero-order hold; tick 0
        alone, before the reference knows the tick period). Tick 0 is re-sent until then
        (discovery); a re-sent later tick would only repeat messages."""
        for _ in range(ticks):
            self.k += 1
            t = self.k * TS
            known = t + TS if self.k else t
            self.clock.publish(clock_msg(t))
            assert self.probe.wait_for(lambda: any(s >= known for s, _ in self.setpoints)
                                       or (t == 0 and self.clock.publish(clock_msg(t))), 20), t

    def value_at(self, t: int) -> float:
        """The setpoint in force at ``t`` (zero-order hold: the latest stamped at or before)."""
        return max(m for m in self.setpoints if m[0] <= t)[1]

    def call(self, future):
        assert self.probe.wait_for(future.done, 20)
        return future.result()

    def set(self, **values):
        """One set_parameters call carrying every given parameter of channel y."""
        params = [Parameter(f'setpoint.y.{k}', value=v) for k, v in values.items()]
        return self.call(self.client.set_parameters(params)).results

    def parameters(self) -> dict:
        names = [f'setpoint.y.{f}' for f in (*FIELDS, 'value')]
        values = self.call(self.client.get_parameters(names)).values
        out = {n.split('.')[-1]: Parameter.from_parameter_msg(ParameterMsg(name=n, value=v)).value
               for n, v in zip(names, values)}
        return {k: list(v) if k in ('times', 'values') else v for k, v in out.items()}

    def runs_its_parameters(self, ticks: int = 8) -> dict:
        """The parameters describe a valid schedule, and every setpoint published after they
        were read (in the next ``ticks`` ticks: at least a hold every 6) is that schedule's
        value at its stamp."""
        params = self.parameters()
        schedule = ChannelSchedule(**{f: tuple(params[f]) if f in ('times', 'values')
                                      else params[f] for f in FIELDS})
        assert schedule.check('setpoint.y') is None, params
        seen = max(s for s, _ in self.setpoints)
        self.tick(ticks)
        later = [(s, v) for s, v in self.setpoints if s > seen]
        assert later and all(v == schedule.at(s / 1e9) for s, v in later), (params, later)
        return params


def test_parameters_equal_the_running_schedule_and_lists_change_together(
        procs, ros_env, node_cmd, probe, tmp_path):
    path = tmp_path / 'reference.yaml'
    path.write_text(json.dumps({'reference': {'ros__parameters': {
        'clock_mode': 'lockstep', 'setpoint.channels': ['y'],
        'setpoint.y.times': [0.0, 2.0], 'setpoint.y.values': [0.0, 1.0],
        'disturbance.channels': ['v'], 'disturbance.v.value': 0.0}}}))
    proc = procs.start('reference', node_cmd('reference_node', '--params-file', str(path)),
                       env=ros_env)
    ref = Reference(probe)
    ref.tick(25)                                            # t = 2.4 s: past the step
    # New limits keep the future; the past folds into the value reached: written back.
    assert ref.set(max=2.0)[0].successful
    params = ref.runs_its_parameters()
    assert (params['times'], params['values'], params['max']) == ([0.0], [1.0], 2.0)
    # A lone times list of the schedule's length is a schedule; one of another length is
    # refused with the reason, and nothing changes.
    assert ref.set(times=[1.0])[0].successful
    assert ref.runs_its_parameters()['times'] == [1.0]
    [refused] = ref.set(times=[0.0, 2.0])
    assert not refused.successful and 'set both together' in refused.reason
    # Both lists in one call (what `ros2 param load` sends): one change, accepted ...
    answered = max(s for s, _ in ref.setpoints)   # at most 6 ticks past t = 4.0 s
    results = ref.set(times=[0.0, 4.0], values=[0.5, 1.5])
    assert [r.successful for r in results] == [True, True], results
    params = ref.runs_its_parameters(20)                    # to t = 5.7 s: across 4.0
    assert (params['times'], params['values']) == ([0.0, 4.0], [0.5, 1.5])
    # acting from the first tick not yet published (docs/nodes.md: lockstep publishes
    # lockstep.lookahead, 6, ticks ahead)
    assert answered <= 4_600_000_000
    assert {v for s, v in ref.setpoints if s > answered} == {1.5}
    # ... and refused as one when the pair is inconsistent (every result says why).
    results = ref.set(times=[0.0, 1.0, 2.0], values=[0.5, 1.5])
    assert not any(r.successful for r in results)
    assert all('3 times but 2 values' in r.reason for r in results), results
    # A values list of the schedule's length alone: applied, and what runs.
    assert ref.set(values=[0.25, 1.75])[0].successful
    assert ref.runs_its_parameters()['values'] == [0.25, 1.75]
    # An operator override and a ramp: the parameters describe what runs from then on.
    published = max(s for s, _ in ref.setpoints)
    assert ref.set(value=1.25)[0].successful
    assert ref.runs_its_parameters()['value'] == 1.25
    assert {v for s, v in ref.setpoints if s > published} == {1.25}
    assert ref.set(ramp_rate=0.5)[0].successful
    assert ref.set(value=0.75)[0].successful
    # ramping down 0.05 per tick from the first tick not yet published (at most 6 ahead)
    ref.runs_its_parameters(18)
    assert ref.value_at(ref.k * TS) == 0.75
    # `ros2 param load` of both lists through the project's CLI.
    load = tmp_path / 'load.yaml'
    load.write_text(json.dumps({'/reference': {'ros__parameters': {
        'setpoint.y.times': [0.0, 8.0, 9.0], 'setpoint.y.values': [0.5, 1.0, 2.0],
        'setpoint.y.ramp_rate': 0.0}}}))
    result = ros2(ros_env, 'param', 'load', '/reference', str(load), '--timeout', '30')
    assert result.returncode == 0, (result.stdout, result.stderr, proc.tail())
    params = ref.runs_its_parameters(30)                    # to t ≈ 9.4 s
    assert (params['times'], params['values']) == ([0.0, 8.0, 9.0], [0.5, 1.0, 2.0])
    assert ref.value_at(ref.k * TS) == 2.0
    # A dump of the node loads back, unchanged.
    dump = ros2(ros_env, 'param', 'dump', '/reference', '--timeout', '30')
    assert dump.returncode == 0, dump.stderr
    (tmp_path / 'dump.yaml').write_text(dump.stdout)
    result = ros2(ros_env, 'param', 'load', '/reference', str(tmp_path / 'dump.yaml'),
                  '--timeout', '30')
    assert result.returncode == 0, (result.stdout, result.stderr)
    assert ref.runs_its_parameters() == params
    assert 'not applied' not in proc.tail(200)
