"""A costly tuning design in wall mode runs off the sampling path (nodes/live_derive.py, issue
"operate a loop" §7): after ``set_parameters(tuning.ms_target ...)`` returns, samples go on at
their period with the running gains while the Ms design runs; then the derived gains appear as
parameters and take effect without an output jump; a design the node refuses sets the
``tuning.*`` value back and says why. A real controller_node (in the test process, its design
held by the test's gate) over DDS."""
from __future__ import annotations

import json
import threading

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from tank_control.core.scenario import controller_setup
from tank_control.core.tuning import robust, rules
from tank_control.nodes.params import AUDIT_QOS, AUDIT_TOPIC
from tank_control.nodes.messages import ORIGIN_QOS, SIGNAL_QOS, ns_to_stamp, to_joint_state

WAIT = 30.0          # s: a loaded machine; every wait ends at its event
H = 0.5              # s: the sample time
GATE = threading.Event()      # the worker's design waits for it (the test holds it)
MODEL = {'tuning.rule': 'ms', 'tuning.gain': 1.0, 'tuning.dead_time': 0.5,
         'tuning.time_constant': 2.0, 'robustness.ms_max': 1.6}
GAINS = ('kp', 'ti', 'td', 'b', 'c')


@pytest.fixture
def node(probe, monkeypatch):
    from tank_control.nodes.controller_node import ControllerNode
    design = robust.ms_design

    def held_design(*args, **kwargs):        # the Ms search waits for the test's gate
        assert GATE.wait(WAIT), 'the design was held on the sampling path'
        return design(*args, **kwargs)
    monkeypatch.setattr(robust, 'ms_design', held_design)
    rules._ms_design.cache_clear()           # every design of this test is searched anew
    GATE.set()
    ctrl = ControllerNode(parameter_overrides=[
        Parameter('controller', value='pid'), Parameter('clock_mode', value='wall'),
        Parameter('trigger', value='measurement'), Parameter('sample_time', value=H),
        Parameter('diagnostics_period', value=0.1), Parameter('initial_output', value=[2.0]),
        *(Parameter(k, value=v) for k, v in MODEL.items())])
    probe.executor.add_node(ctrl)
    yield ctrl
    GATE.set()
    probe.executor.remove_node(ctrl)
    ctrl.destroy_node()


def _expected(**changes: float) -> dict[str, float]:
    """The gains the synchronous derivation gives (lockstep, sim, in-process)."""
    values = {'controller': 'pid', 'sample_time': H, **MODEL, **changes}
    settings = controller_setup(values).settings
    return {k: settings.values[k] for k in GAINS}


def test_an_ms_design_runs_while_sampling_goes_on_and_a_refused_one_is_set_back(probe, node):
    pnode = probe.node
    meas = pnode.create_publisher(JointState, 'measurement', SIGNAL_QOS)
    setp = pnode.create_publisher(JointState, 'setpoint', SIGNAL_QOS)
    samples: list[tuple[int, float]] = []          # (stamp ns, output)
    diag: list[str] = []
    audit: list[dict] = []
    pnode.create_subscription(String, AUDIT_TOPIC, lambda m: audit.append(json.loads(m.data)),
                              AUDIT_QOS)
    pnode.create_subscription(JointState, 'manipulated', lambda m: samples.append(
        (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.position[0])), SIGNAL_QOS)
    pnode.create_subscription(DiagnosticArray, '/diagnostics', lambda m: diag.extend(
        s.message for s in m.status if s.name.startswith('controller')), 10)
    pnode.create_publisher(Time, 'time_origin', ORIGIN_QOS).publish(
        ns_to_stamp(pnode.get_clock().now().nanoseconds))

    def feed():                       # the plant at rest at the setpoint: a constant output
        now = pnode.get_clock().now().nanoseconds
        setp.publish(to_joint_state(now, ['y'], [1.0]))
        meas.publish(to_joint_state(now, ['y'], [1.0]))
    pnode.create_timer(0.05, feed)

    def next_samples(n: int) -> list[tuple[int, float]]:
        start = len(samples)
        assert probe.wait_for(lambda: len(samples) >= start + n, WAIT)
        return samples[start:start + n]

    before = {k: node.get_parameter(k).value for k in GAINS}
    assert before == pytest.approx(_expected())
    u0 = next_samples(3)[-1][1]
    # tuning.ms_target 1.4 -> 1.5 with the design held: accepted at once, sampling goes on
    GATE.clear()
    result = node.set_parameters([Parameter('tuning.ms_target', value=1.5)])[0]
    assert result.successful, result.reason
    held = next_samples(5)
    stamps = [s for s, _ in held]
    # five sample instants went by with the design held, each answered by the running law
    assert stamps == sorted(set(stamps)), stamps
    assert [u for _, u in held] == pytest.approx([u0] * 5)                  # the running law
    assert {k: node.get_parameter(k).value for k in GAINS} == before        # not yet derived
    assert node.get_parameter('tuning.ms_target').value == 1.5
    GATE.set()
    new = _expected(**{'tuning.ms_target': 1.5})
    assert new['kp'] != pytest.approx(before['kp'])
    assert probe.wait_for(lambda: all(node.get_parameter(k).value == pytest.approx(v)
                                      for k, v in new.items()), WAIT)
    assert probe.wait_for(lambda: any(a['name'] == 'kp' and a['new'] == pytest.approx(new['kp'])
                                      and a['source'] == 'derived from tuning.ms_target'
                                      for a in audit), WAIT), audit[-3:]
    after = next_samples(3)
    assert [u for _, u in after] == pytest.approx([u0] * 3)      # no output jump
    assert node._controller.pid.config.kp == pytest.approx(new['kp'])   # the new law runs

    # a design the guard refuses (Ms 2 > robustness.ms_max 1.6): set back, said why
    GATE.set()
    result = node.set_parameters([Parameter('tuning.ms_target', value=2.0)])[0]
    assert result.successful, result.reason      # accepted: only the design can tell
    assert probe.wait_for(lambda: node.get_parameter('tuning.ms_target').value == 1.5, WAIT)
    assert probe.wait_for(lambda: any('robustness.ms_max 1.6' in m and
                                      'tuning.ms_target set back to 1.5' in m for m in diag),
                          WAIT), diag[-3:]
    assert {k: node.get_parameter(k).value for k in GAINS} == pytest.approx(new)
    assert node._controller.pid.config.kp == pytest.approx(new['kp'])
    assert node.counters['update_errors'] == 1
    assert [u for _, u in next_samples(3)] == pytest.approx([u0] * 3)
    seen = len(diag)                  # /diagnostics goes on naming it at the later samples
    assert probe.wait_for(lambda: len(diag) > seen, WAIT)
    assert 'tuning.ms_target set back to 1.5' in diag[-1], diag[-1]
