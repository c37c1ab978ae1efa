"""A whole wall-clock loop under the harness (the real plant, controller and reference nodes)
with one message stamped in the future injected on each signal topic: the loop
keeps running — the setpoint step at 10 s acts at 10 s — and the harness's recorder does not
record them (``rejected_future`` in metrics.json). Before, the measurement stamped 10 s ahead
froze the controller's samples, the manipulated one the plant's input, the setpoint one the
setpoint (the step never acted), and the recorder took the measurement as the run's time."""
from __future__ import annotations

import json
import sys

from sensor_msgs.msg import JointState
from support import CONFIG

from tank_control.core.interfaces import to_ns
from tank_control.core.trace import Trace
from tank_control.nodes.messages import SIGNAL_QOS, from_joint_state, to_joint_state


def test_one_message_stamped_in_the_future_on_each_signal_does_not_freeze_a_wall_loop(
        tmp_path, procs, ros_env, probe):
    out = tmp_path / 'run'
    run = procs.start('harness', [sys.executable, '-m', 'tank_control.harness.cli', 'run',
                                  str(CONFIG / 'ipdt_pid.yaml'), '--mode', 'wall', '--duration',
                                  '14', '--out', str(out), '--quiet', '--no-plots'], env=ros_env)
    node = probe.node
    latest: list[int] = []
    node.create_subscription(JointState, 'measurement',
                             lambda m: latest.append(from_joint_state(m)[0]), SIGNAL_QOS)
    # the writers only once the run is on (the harness refuses to start beside another graph)
    assert probe.wait_for(lambda: len(latest) >= 10, 120), run.tail()
    pubs = {topic: node.create_publisher(JointState, topic, SIGNAL_QOS)
            for topic in ('measurement', 'setpoint', 'manipulated', 'disturbance')}
    # every reader matched (the recorder and the node)
    assert probe.wait_for(lambda: all(p.get_subscription_count() >= 2 for p in pubs.values()),
                          60), run.tail()
    assert latest[-1] - latest[0] < to_ns(8.0), 'matched too late to inject before 10 s'
    ahead = latest[-1] + to_ns(10.0)
    pubs['measurement'].publish(to_joint_state(ahead, ['y'], [0.5]))
    pubs['manipulated'].publish(to_joint_state(ahead, ['u'], [0.0]))
    pubs['disturbance'].publish(to_joint_state(ahead, ['v'], [0.0]))
    pubs['setpoint'].publish(to_joint_state(latest[-1] + to_ns(3600.0), ['y'], [0.0]))
    assert run.popen.wait(timeout=300) == 0, run.tail(30)
    trace = Trace.read_csv(out / 'trace.csv')
    t, r, u = trace.t, trace.columns['r.y'], trace.columns['u.u']
    before = [ui for ti, ui in zip(t, u) if 9.0 <= ti < 10.0]
    after = [(ti, ri, ui) for ti, ri, ui in zip(t, r, u) if 10.0 <= ti <= 13.0]
    assert before and after and max(abs(x) for x in before) < 1e-9, before
    assert all(ri == 1.0 for _, ri, _ in after), after[:3]          # the step is in force
    assert all(ui > 0.5 for _, _, ui in after), after[:3]           # and acts at once
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['run']['rejected_future'] == 4
    logs = out / 'logs'
    assert 'refused' in (logs / 'controller.log').read_text()
    assert 'refused' in (logs / 'plant.log').read_text()
