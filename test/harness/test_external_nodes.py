"""The harness tests a node it did not start (``harness.external_nodes``, docs/harness.md
"External nodes"): a controller written here with bare rclpy, not importing tank_control,
that follows the lockstep protocol of docs/nodes.md ("Writing a node of your own"), is run in
lockstep and in sim beside the harness's plant_node and reference_node; its trace equals the
same law run by the in-process loop. A controller that never comes ends the run after the
bounded wait, with one line saying what was missing."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from support.mcap import stamps_and_arrivals

from tank_control.core import loop as core_loop
from tank_control.core import scenario as core_scenario
from tank_control.core.trace import Trace
from tank_control.harness.runner import RunFailed, run_scenario
from tank_control.harness.scenario_file import ScenarioError, load_scenario, node_parameters
from tank_control.ros2cli.common import is_hidden

KP, TI, TS = 3.14, 18.66, 0.1
#: The control law, once: executed by the external node (as text) and by the in-process twin.
LAW = f'''
def law(state, e):
    """PI, integral by forward rectangles; state = [integral]."""
    u = {KP!r} * e + state[0]
    state[0] = state[0] + {KP * TS / TI!r} * e
    return u
'''

#: The external controller: bare rclpy and sensor_msgs only (no tank_control import).
EXTERNAL = '''
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
''' + LAW + '''

def ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec

class Controller(Node):
    def __init__(self):
        super().__init__('controller')
        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(JointState, 'manipulated', qos)
        self.create_subscription(JointState, 'measurement', self.on_measurement, qos)
        self.create_subscription(JointState, 'setpoint', self.on_setpoint, qos)
        self.setpoints = []     # (stamp, r): each holds from its stamp until the next one
        self.waiting = []       # measurements whose setpoint is not known yet
        self.answers = {}       # stamp -> answer: a re-sent tick gets the same answer again
        self.state = [0.0]

    def on_setpoint(self, msg):
        s = ns(msg.header.stamp)      # a stamp at or before one held restarts the stream there
        self.setpoints = [p for p in self.setpoints if p[0] < s]
        self.setpoints.append((s, msg.position[list(msg.name).index('y')]))
        self.answer()

    def on_measurement(self, msg):
        self.waiting.append(msg)
        self.answer()

    def answer(self):
        while self.waiting:
            msg = self.waiting[0]
            t = ns(msg.header.stamp)
            if t not in self.answers:
                if not self.setpoints or self.setpoints[-1][0] < t:
                    return                # the setpoint of t is known once one stamped >= t came
                held = [v for s, v in self.setpoints if s <= t]
                if not held:              # the setpoint of t was lost (sim: sent before we
                    self.waiting.pop(0)   # matched the reference): t cannot be answered
                    continue
                y = msg.position[list(msg.name).index('y')]
                out = JointState(name=['u'], position=[law(self.state, held[-1] - y)])
                out.header.stamp = msg.header.stamp          # the measurement's instant
                self.answers[t] = out
            self.pub.publish(self.answers[t])
            self.waiting.pop(0)

rclpy.init()
node = Controller()
try:
    rclpy.spin(node)
except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
    pass
'''


class InProcessLaw:
    """The same law as an in-process controller (``core.interfaces.Controller``)."""

    output_names = ('y',)
    input_names = ('u',)
    disturbance_names = ()
    sample_time = TS

    def __init__(self) -> None:
        scope: dict = {}
        exec(LAW, scope)              # noqa: S102 - the law above, shared with the node
        self.law, self.state = scope['law'], [0.0]

    def reset(self, y, u) -> None:
        raise AssertionError('the in-process loop never resets a controller without '
                             'initial_output on a clean run')

    def step(self, t, y, r, d):
        return np.array([self.law(self.state, float(r[0]) - float(y[0]))])

    def status(self):
        return {}


SCENARIO = """
plant:
  ros__parameters: {plant: ipdt, sample_time: 0.1, gain: 0.05, dead_time: 2.0,
                    noise_std: [0.01], seed: 7}
reference:
  ros__parameters:
    setpoint.channels: ['y']
    setpoint.y.times: [0.0, 2.0]
    setpoint.y.values: [0.0, 1.0]
    disturbance.channels: ['v']
    disturbance.v.times: [0.0, 15.0]
    disturbance.v.values: [0.0, -0.1]
harness:
  ros__parameters: {duration: 30.0, external_nodes: ['controller'], external_wait: 120.0}
"""


@pytest.fixture
def scenario_path(tmp_path: Path) -> Path:
    path = tmp_path / 'external.yaml'
    path.write_text(SCENARIO)
    return path


def in_process_trace(scenario) -> Trace:
    """The loop with the in-process twin of the law, on the plant, noise and reference the
    ROS run uses (scenario.yaml's sections, a pid section only to build the rest)."""
    sections = node_parameters(scenario)
    sections['controller'] = {'controller': 'pid', 'sample_time': TS}
    built = core_scenario.build(sections)
    return core_loop.run_loop(built.plant, InProcessLaw(), built.reference,
                              sample_time=built.sample_time, duration=scenario.harness.duration,
                              noise=built.noise.sample_floats, guards=built.guards())


def start_external(procs, tmp_path: Path, env) -> None:
    script = tmp_path / 'my_controller.py'
    script.write_text(EXTERNAL)
    procs.start('my_controller', [sys.executable, str(script)], env=env)


def test_the_external_script_does_not_import_tank_control():
    assert 'tank_control' not in EXTERNAL


@pytest.mark.parametrize('mode', ['lockstep', 'sim'])
def test_an_external_bare_rclpy_controller_is_run_and_recorded_as_its_in_process_twin(
        mode, scenario_path, tmp_path, procs, ros_env):
    overrides = ['harness.clock_mode=' + mode]
    if mode == 'sim':
        overrides.append('harness.real_time_factor=5.0')
    scenario = load_scenario(scenario_path, overrides)
    start_external(procs, tmp_path, ros_env)
    result = run_scenario(scenario, tmp_path / 'out', env=ros_env, plots=False)
    trace = Trace.read_csv(result.files['trace'])
    expected = in_process_trace(scenario)
    assert list(trace.columns) == list(expected.columns) == ['t', 'y.y', 'r.y', 'u.u', 'd.v']
    assert len(trace) == len(expected) == 301
    metrics = result.metrics
    assert metrics['complete'] is True
    assert 'controller' not in metrics['run']['exit_codes']        # not started by the harness
    # nor taken for a stranger; the only other node on the session's domain may be the
    # `ros2` daemon an earlier test's command left running (hidden: `_ros2cli_daemon_…`)
    foreign = [n['node'] for n in metrics['run']['foreign_nodes']]
    assert all(is_hidden(name) for name in foreign), foreign
    (step,) = metrics['outputs']['y']['steps']
    assert step['t'] == pytest.approx(2.0) and step['r_to'] == 1.0
    if mode == 'lockstep':
        assert np.all(np.isfinite(trace['u.u']))      # every tick answered by the external node
        for name in trace.columns:
            np.testing.assert_allclose(trace[name], expected[name], rtol=0, atol=1e-9,
                                       err_msg=name)
        assert metrics['run']['late_samples'] == 0
    else:
        # sim waits for nobody: the first setpoints may reach the external node before its
        # reader matched the reference's writer (it cannot answer those ticks), the plant may
        # apply an answer late on a busy machine, and the run may end before the last ticks'
        # answers come (the trace holds the previous one there); but from its first answer on,
        # each row it answered (an answer stamped with that row's tick in run.mcap) holds the
        # law of that row's measurement and setpoint
        u_col = trace['u.u']
        first = int(np.argmax(np.isfinite(u_col)))
        assert np.isfinite(u_col[first]) and first < len(trace) // 2
        answered = {round(stamp / 1e9 / TS) for stamp, _ in
                    stamps_and_arrivals(result.files['recording'], '/manipulated')}
        rows = np.asarray([i for i in range(first, len(trace))
                           if round(trace.t[i] / TS) in answered])
        assert len(rows) >= (len(trace) - first) // 2, (len(rows), len(trace) - first)
        twin = InProcessLaw()
        u = np.asarray([float(twin.step(t, [y], [r], [])[0]) for t, y, r in
                        zip(trace.t[first:], trace['y.y'][first:], trace['r.y'][first:])])
        np.testing.assert_allclose(u_col[rows], u[rows - first], rtol=0, atol=1e-9)
        assert abs(trace['y.y'][-1] - 1.0) < 0.2                   # and it controls the loop


def _still_running(marker: str) -> list[str]:
    """Command lines of this user's processes that name ``marker``."""
    found = []
    for proc in Path('/proc').iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            cmdline = (proc / 'cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace')
        except OSError:
            continue
        if marker in cmdline:
            found.append(cmdline)
    return found


def test_an_external_controller_that_never_comes_ends_the_run_after_the_bounded_wait(
        scenario_path, tmp_path, procs, ros_env):
    out = tmp_path / 'out'
    run = procs.start('harness', [sys.executable, '-m', 'tank_control.harness.cli', 'run',
                                  str(scenario_path), '--out', str(out), '--quiet', '--no-plots',
                                  '--set', 'harness.external_wait=3.0'], env=ros_env)
    assert run.popen.wait(timeout=180) == 1, run.tail(30)
    log = run.log_path.read_text()
    assert ('tank-control: waiting for the external controller: no node named controller in '
            'the graph yet (0 s of 3 s, harness.external_wait)') in log
    assert ('run failed: the external controller did not come within 3 s '
            '(harness.external_wait): no node named controller in the graph yet') in log
    assert 'Traceback' not in log
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['complete'] is False and 'harness.external_wait' in metrics['reason']
    assert _still_running(str(out / 'scenario.yaml')) == []      # its plant and reference ended


def test_external_nodes_are_checked_before_anything_starts(scenario_path, tmp_path):
    with pytest.raises(ScenarioError, match="external_nodes: 'controller' is not one of nodes"):
        load_scenario(scenario_path, ['harness.nodes=[plant, reference]'])
    with pytest.raises(ScenarioError, match='every node of the loop is external'):
        load_scenario(scenario_path, ['harness.external_nodes=[plant, controller, reference]'])
    with pytest.raises(ScenarioError, match='harness.external_wait'):
        load_scenario(scenario_path, ['harness.external_wait=0.1'])
    with pytest.raises(ScenarioError, match='an --in-process run cannot include'):
        run_scenario(load_scenario(scenario_path), tmp_path / 'out', in_process=True)


def test_an_external_controller_is_accepted_but_any_other_foreign_publisher_is_refused(
        scenario_path, tmp_path, procs, shared_ros_env, probe):
    """Somebody else is on the domain (the external controller, a stranger): the harness looks
    for another graph before it starts a node (docs/harness.md, step 2), takes the external
    controller for the run's and refuses the stranger's publisher."""
    from sensor_msgs.msg import JointState
    ros_env = shared_ros_env
    start_external(procs, tmp_path, ros_env)
    probe.node.create_publisher(JointState, 'setpoint', 10)       # a stranger in the loop
    assert probe.wait_for(lambda: 'controller' in probe.node.get_node_names(), 60.0)
    with pytest.raises(RunFailed, match='another graph') as failed:
        run_scenario(load_scenario(scenario_path), tmp_path / 'out', env=ros_env)
    reason = str(failed.value)
    assert f'publisher of /setpoint ({probe.node.get_name()})' in reason
    assert 'controller' not in reason


PLANT_SCENARIO = """
plant:
  ros__parameters: {plant: ipdt, sample_time: 0.1, gain: 0.05, dead_time: 2.0,
                    noise_std: [0.01], seed: 7, clock_mode: lockstep, real_time_factor: 0.0}
controller:
  ros__parameters: {controller: pid, sample_time: 0.1, kp: 3.14, ti: 18.66,
                    output_names: ['y'], input_names: ['u']}
reference:
  ros__parameters:
    setpoint.channels: ['y']
    setpoint.y.times: [0.0, 2.0]
    setpoint.y.values: [0.0, 1.0]
    disturbance.channels: ['v']
    disturbance.v.times: [0.0, 15.0]
    disturbance.v.values: [0.0, -0.1]
harness:
  ros__parameters: {duration: 30.0, external_nodes: ['plant'], external_wait: 120.0}
"""


def test_an_external_plant_node_started_paused_is_released_and_recorded_from_tick_0(
        tmp_path, procs, node_cmd, ros_env):
    """The user runs the plant (here plant_node, started paused with the recording window, as
    docs/harness.md says): the harness starts controller and reference, releases the plant's
    clock once the graph is up, and the trace equals the in-process run row for row."""
    path = tmp_path / 'external_plant.yaml'
    path.write_text(PLANT_SCENARIO)
    procs.start('my_plant', node_cmd('plant_node', '--params-file', str(path), '-p',
                                     'lockstep.paused:=true', '-p',
                                     'lockstep.record_window:=8'), env=ros_env)
    scenario = load_scenario(path)
    result = run_scenario(scenario, tmp_path / 'out', env=ros_env, plots=False)
    trace = Trace.read_csv(result.files['trace'])
    built = core_scenario.build(node_parameters(scenario))
    expected = core_scenario.run(built, scenario.harness.duration)
    assert len(trace) == len(expected) == 301
    for name in expected.columns:
        np.testing.assert_allclose(trace[name], expected[name], rtol=0, atol=1e-9, err_msg=name)
    assert 'plant' not in result.metrics['run']['exit_codes']
    assert result.metrics['controller']['final_gains']['kp'] == 3.14   # its own controller
