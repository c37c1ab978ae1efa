"""controller_node's plug-in points for later kinds (relay_autotune, mpcs): operator commands
as Trigger services and controller results written back to parameters. The node runs in the
test process (so a test-only kind can be registered) on the probe's executor."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind, group
from tank_control.core.params import param
from tank_control.nodes.messages import SIGNAL_QOS, stamp_to_ns, to_joint_state


class _Counting:
    """u = number of samples since the 'start' command (0 before); a stand-in for a tuner."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()
    sample_time = 1.0

    def __init__(self):
        self.running = False
        self.count = 0

    def reset(self, y, u):
        pass

    def step(self, t, y, r, d):
        if self.running:
            self.count += 1
        return np.array([float(self.count)])

    def start(self):
        if self.running:
            return False, 'already running'
        self.running = True
        return True, 'started'

    @property
    def status(self):
        return {'state': 'running' if self.running else 'idle'}


@dataclass(frozen=True)
class SampleTime:
    sample_time: float = param(1.0, 'sample time', unit='s', min=0.1, max=10.0, read_only=True)


@dataclass(frozen=True)
class CountingResults:
    count: int = param(0, 'samples counted (result)', min=0, max=10**6, read_only=True,
                       name='counting.count')
    state: str = param('idle', 'state (result)', read_only=True, name='counting.state')


COUNTING = ControllerKind(
    name='counting', description='counts samples after start', config=SampleTime,
    groups=(group('results', CountingResults),), build=lambda settings: _Counting(),
    results=lambda c: {'counting.count': c.count, 'counting.state': c.status['state']},
    commands={'start': lambda c: c.start()})


@pytest.fixture
def node(probe, monkeypatch):
    from tank_control.nodes.controller_node import ControllerNode
    monkeypatch.setitem(registry.KINDS, 'counting', COUNTING)
    ctrl = ControllerNode(parameter_overrides=[Parameter('controller', value='counting'),
                                               Parameter('clock_mode', value='lockstep')])
    probe.executor.add_node(ctrl)
    yield ctrl
    probe.executor.remove_node(ctrl)
    ctrl.destroy_node()


def test_commands_are_services_and_results_become_parameters(probe, node):
    meas = probe.node.create_publisher(JointState, 'measurement', SIGNAL_QOS)
    setp = probe.node.create_publisher(JointState, 'setpoint', SIGNAL_QOS)
    answers = {}
    probe.node.create_subscription(
        JointState, 'manipulated',
        lambda m: answers.__setitem__(stamp_to_ns(m.header.stamp), m.position[0]), SIGNAL_QOS)

    def tick(k):
        t_ns = k * 1_000_000_000
        while t_ns not in answers:
            meas.publish(to_joint_state(t_ns, ['y'], [0.0]))
            setp.publish(to_joint_state(t_ns, ['y'], [0.0]))
            probe.wait_for(lambda: t_ns in answers, 0.5)
        return answers[t_ns]

    assert tick(0) == 0.0
    client = probe.node.create_client(Trigger, '/controller/start')
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(Trigger.Request())
    assert probe.wait_for(future.done, 10.0)
    assert future.result().success and future.result().message == 'started'
    seen = []
    node.sample_observers.append(lambda t_ns, y, r, d, u, fault: seen.append(
        (t_ns, u.tolist(), fault)))
    assert [tick(k) for k in (1, 2, 3)] == [1.0, 2.0, 3.0]
    # a feature hook: each sample's (plant time, y, r, d, u, fault) is handed to the observers
    assert seen == [(k * 1_000_000_000, [float(k)], '') for k in (1, 2, 3)]
    assert node.get_parameter('counting.count').value == 3
    assert node.get_parameter('counting.state').value == 'running'
    # results stay read-only for users
    assert not node.set_parameters([Parameter('counting.count', value=0)])[0].successful
    again = client.call_async(Trigger.Request())
    assert probe.wait_for(again.done, 10.0) and not again.result().success


class _FeedForward:
    """u = −v: uses the measured disturbance v (feed-forward), as MPCS uses F_D."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ('v',)
    sample_time = 1.0
    status = {'mode': 'auto'}

    def reset(self, y, u):
        pass

    def step(self, t, y, r, d):
        return np.array([-float(d[0])])


FEEDFORWARD = ControllerKind(name='feedforward', description='u = -v', config=SampleTime,
                             build=lambda settings: _FeedForward())


def test_lockstep_waits_for_the_disturbance_of_the_tick(probe, monkeypatch):
    from tank_control.nodes.controller_node import ControllerNode
    monkeypatch.setitem(registry.KINDS, 'feedforward', FEEDFORWARD)
    ctrl = ControllerNode(parameter_overrides=[Parameter('controller', value='feedforward'),
                                               Parameter('clock_mode', value='lockstep')])
    probe.executor.add_node(ctrl)
    try:
        pubs = {topic: probe.node.create_publisher(JointState, topic, SIGNAL_QOS)
                for topic in ('measurement', 'setpoint', 'disturbance')}
        answers = {}
        probe.node.create_subscription(
            JointState, 'manipulated',
            lambda m: answers.__setitem__(stamp_to_ns(m.header.stamp), m.position[0]), SIGNAL_QOS)
        assert probe.wait_for(lambda: all(p.get_subscription_count() for p in pubs.values()), 30)
        pubs['measurement'].publish(to_joint_state(0, ['y'], [0.0]))
        pubs['setpoint'].publish(to_joint_state(0, ['y'], [0.0]))
        assert not probe.wait_for(lambda: 0 in answers, 0.3)      # disturbance of t=0 missing
        pubs['disturbance'].publish(to_joint_state(0, ['v'], [0.25]))
        assert probe.wait_for(lambda: 0 in answers, 20.0) and answers[0] == -0.25
        # a disturbance message without the channel still answers the tick (last value kept)
        t1 = 1_000_000_000
        for topic, names, values in (('measurement', ['y'], [0.0]), ('setpoint', ['y'], [0.0]),
                                     ('disturbance', [], [])):
            pubs[topic].publish(to_joint_state(t1, names, values))
        assert probe.wait_for(lambda: t1 in answers, 20.0) and answers[t1] == -0.25
    finally:
        probe.executor.remove_node(ctrl)
        ctrl.destroy_node()
