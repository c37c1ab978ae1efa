"""A costly live change in wall mode is built off the sampling path (nodes/live_rebuild.py,
issue "operate a loop" §7): the running law keeps sampling while the change is built, the
first sample after it is ready switches without an output jump, and a change whose build
fails leaves the running law untouched, is set back and says why. The node runs in the test
process (a test-only kind whose build the test holds) on the probe's executor, over DDS."""
from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind
from tank_control.core.params import param
from tank_control.nodes.messages import ORIGIN_QOS, SIGNAL_QOS, ns_to_stamp, to_joint_state

WAIT = 30.0          # s: a loaded machine; every wait ends at its event
REFUSED = 13.0       # the gain the slow kind cannot build
GATE = threading.Event()      # the slow kind's build waits for it (the test holds it)


@dataclass(frozen=True)
class SlowGain:
    gain: float = param(1.0, 'u = gain·y + offset', min=0.0, max=100.0, name='slow.gain')
    sample_time: float = param(0.1, 'sample time', unit='s', min=0.01, max=10.0,
                               read_only=True)


class _Proportional:
    """u = gain·y + offset; ``reset(y, u)`` sets the offset (a bumpless start)."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ()

    def __init__(self, cfg: SlowGain):
        self.sample_time = cfg.sample_time
        self.gain, self.offset = cfg.gain, 0.0

    def reset(self, y, u):
        self.offset = float(u[0]) - self.gain * float(y[0])

    def step(self, t, y, r, d):
        return np.array([self.gain * float(y[0]) + self.offset])

    @property
    def status(self):
        return {'mode': 'auto'}


def _update(controller: _Proportional, settings, changed) -> bool:
    """A costly rebuild: waits for the test's gate; the gain 13 cannot be built."""
    assert GATE.wait(WAIT)
    gain = settings.config.gain
    if gain == REFUSED:
        raise ValueError(f'slow.gain {gain:g} cannot be built')
    controller.gain = gain
    return True


SLOW = ControllerKind(name='slowgain', description='u = gain·y (a costly rebuild)',
                      config=SlowGain, build=lambda settings: _Proportional(settings.config),
                      update=_update, slow=('slow.gain',))


@pytest.fixture
def node(probe, monkeypatch):
    from tank_control.nodes.controller_node import ControllerNode
    monkeypatch.setitem(registry.KINDS, 'slowgain', SLOW)
    GATE.set()                     # the start-up build passes
    ctrl = ControllerNode(parameter_overrides=[Parameter('controller', value='slowgain'),
                                               Parameter('clock_mode', value='wall'),
                                               Parameter('trigger', value='measurement'),
                                               Parameter('sample_time', value=0.5),
                                               Parameter('diagnostics_period', value=0.1)])
    probe.executor.add_node(ctrl)
    yield ctrl
    GATE.set()
    probe.executor.remove_node(ctrl)
    ctrl.destroy_node()


def test_a_slow_change_is_built_while_sampling_goes_on_and_a_failed_one_keeps_the_law(
        probe, node):
    pnode = probe.node
    meas = pnode.create_publisher(JointState, 'measurement', SIGNAL_QOS)
    setp = pnode.create_publisher(JointState, 'setpoint', SIGNAL_QOS)
    answers: list[float] = []
    diag: list[str] = []
    pnode.create_subscription(JointState, 'manipulated',
                              lambda m: answers.append(m.position[0]), SIGNAL_QOS)
    pnode.create_subscription(DiagnosticArray, '/diagnostics', lambda m: diag.extend(
        s.message for s in m.status if s.name.startswith('controller')), 10)
    pnode.create_publisher(Time, 'time_origin', ORIGIN_QOS).publish(
        ns_to_stamp(pnode.get_clock().now().nanoseconds))
    y = [1.0]

    def feed():                       # the plant: a measurement every 0.05 s
        now = pnode.get_clock().now().nanoseconds
        setp.publish(to_joint_state(now, ['y'], [0.0]))
        meas.publish(to_joint_state(now, ['y'], [y[0]]))
    pnode.create_timer(0.05, feed)

    def samples(n: int) -> list[float]:
        """The next ``n`` samples' outputs (one per 0.5-s instant)."""
        start = len(answers)
        assert probe.wait_for(lambda: len(answers) >= start + n, WAIT)
        return answers[start:start + n]

    assert samples(3)[-1] == pytest.approx(1.0)         # gain 1, y 1
    # gain 1 -> 4 with the build held: accepted at once, the running law samples on
    GATE.clear()
    result = node.set_parameters([Parameter('slow.gain', value=4.0)])[0]
    assert not GATE.is_set(), 'the change was built inside the parameter callback'
    assert result.successful, result.reason
    held = samples(5)
    assert held == pytest.approx([1.0] * 5)            # the old law, no sample missed
    GATE.set()
    assert probe.wait_for(lambda: node._rebuild is None or node._rebuild.wait(0.05), WAIT)
    switch = samples(1)
    assert switch == pytest.approx([1.0])               # the switch: no output jump
    y[0] = 2.0                        # (the sample after next surely has it)
    assert samples(2)[1] == pytest.approx(5.0)          # then the new gain: 1 + 4·(2 − 1)

    # a change whose build fails: the running law is kept, the value set back, said why
    GATE.set()
    result = node.set_parameters([Parameter('slow.gain', value=REFUSED)])[0]
    assert result.successful, result.reason            # accepted: only the build can tell
    assert probe.wait_for(lambda: node._rebuild is None or node._rebuild.wait(0.05), WAIT)
    samples(2)
    y[0] = 3.0
    assert samples(2)[1] == pytest.approx(9.0)          # still gain 4: 5 + 4·(3 − 2)
    assert node.get_parameter('slow.gain').value == 4.0
    assert probe.wait_for(lambda: any('slow.gain 13 cannot be built' in m and
                                      'slow.gain set back to 4.0' in m for m in diag), WAIT), \
        diag[-3:]
    assert node.counters['update_errors'] == 1
