"""The harness over a real ROS 2 graph, with small stand-in plant and reference nodes
(test/support/standin_nodes.py) and the real controller_node: lockstep trace against an
independent computation, files written, final gains read back, failures reported."""
from __future__ import annotations

import json

import numpy as np
import pytest

from support import CONFIG
from support.mcap import read_mcap
from support.standins import SCENARIO, standin_command, standin_scenario
from tank_control.core.control.pid import Pid2Dof, PidConfig
from tank_control.core.trace import Trace
from tank_control.harness.runner import RunFailed, run_scenario
from tank_control.harness.scenario_file import ScenarioError, load_scenario

@pytest.fixture
def scenario_path(tmp_path):
    path = tmp_path / 'standin.yaml'
    path.write_text(SCENARIO)
    return path


def expected_trace(duration=6.0, ts=0.1, cts=0.2):
    """The same loop computed here: integrator plant, core PID at every 2nd tick."""
    pid = Pid2Dof(PidConfig(kp=1.5, ti=4.0, b=0.5, sample_time=cts, u_min=-1.0, u_max=1.2))
    y, u, rows = 0.0, 0.0, []
    for k in range(int(round(duration / ts)) + 1):
        t = k * 100_000_000 / 1e9
        r = 1.0 if k * 100_000_000 >= 1_000_000_000 else 0.0
        if (k * 100_000_000) % 200_000_000 == 0:
            u = pid.update(r, y)
        rows.append((t, y, r, u))
        y = y + ts * u
    return np.array(rows)


def test_lockstep_run_matches_independent_loop_and_writes_every_file(scenario_path, tmp_path,
                                                                      ros_env):
    progress = []
    result = run_scenario(standin_scenario(scenario_path), tmp_path / 'out', env=ros_env,
                          node_command=standin_command, progress=progress.append)
    trace = Trace.read_csv(result.files['trace'])
    assert list(trace.columns) == ['t', 'y.y', 'r.y', 'u.u']
    expected = expected_trace()
    assert len(trace) == len(expected) == 61
    for i, name in enumerate(['t', 'y.y', 'r.y', 'u.u']):
        np.testing.assert_allclose(trace.columns[name], expected[:, i], rtol=0, atol=1e-9)

    metrics = json.loads(result.files['metrics'].read_text())
    run = metrics['run']
    assert run['missed_samples'] == 0 and run['late_samples'] == 0 and run['max_jitter'] == 0.0
    assert run['ticks'] == 61 and run['sim_duration'] == pytest.approx(6.0)
    # CPU per tick of every node process and of the harness, during the run
    assert set(run['cpu_ms_per_tick']) == set(run['exit_codes']) | {'harness'}
    assert all(0 <= ms < 1e3 for ms in run['cpu_ms_per_tick'].values())
    assert run['cpu_ms_per_tick']['harness'] > 0
    assert metrics['controller']['final_gains'] == {'kp': 1.5, 'ti': 4.0, 'td': 0.0, 'n': 10.0,
                                                    'b': 0.5, 'c': 1.0}
    (step,) = metrics['outputs']['y']['steps']
    assert step['t'] == pytest.approx(1.0) and step['r_to'] == 1.0
    u = metrics['inputs']['u']
    assert u['max'] == pytest.approx(expected[:, 3].max()) and u['constraint_violations'] == 0
    assert progress and progress[-1].sim_time == pytest.approx(6.0)

    topics = read_mcap(result.files['recording'])
    assert {'/measurement', '/setpoint', '/manipulated', '/disturbance', '/clock'} <= set(topics)
    stamps = {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in topics['/manipulated']}
    assert {k * 100_000_000 for k in range(61)} <= stamps
    assert result.files['plot'].read_bytes()[:4] == b'\x89PNG'
    assert (tmp_path / 'out' / 'logs' / 'controller.log').exists()


def test_a_crashing_node_ends_the_run_with_its_last_log_lines_and_keeps_what_was_recorded(
        scenario_path, tmp_path, ros_env):
    """The plant dies at t = 2 s of 6: the run fails with its log lines, and the ticks recorded
    until then stay — trace.csv equal to the independent loop, run.mcap readable, metrics.json
    marked incomplete with the reason."""
    scenario = standin_scenario(scenario_path, ('plant.crash_at=2.0',))
    out = tmp_path / 'out'
    with pytest.raises(RunFailed, match='node plant exited with code 3') as info:
        run_scenario(scenario, out, env=ros_env, node_command=standin_command)
    assert 'crashing on purpose' in str(info.value)

    trace = Trace.read_csv(out / 'trace.csv')
    expected = expected_trace()
    assert 1 <= len(trace) <= 20                 # ticks 0 … 1.9 s at most: tick 2.0 never came
    for i, name in enumerate(['t', 'y.y', 'r.y', 'u.u']):
        np.testing.assert_allclose(trace.columns[name], expected[:len(trace), i], rtol=0,
                                   atol=1e-9)
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['complete'] is False
    assert metrics['reason'].startswith('node plant exited with code 3')
    assert metrics['run']['ticks'] == len(trace)
    stamps = {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
              for m in read_mcap(out / 'run.mcap')['/measurement']}
    assert {round(t * 1e9) for t in trace.t} <= stamps


def test_a_node_that_refuses_its_parameters_fails_the_start(scenario_path, tmp_path, ros_env):
    """The harness refuses a value the real controller_node would refuse before anything
    starts; a node that refuses at start-up all the same ends the run with its reason."""
    with pytest.raises(ScenarioError, match=r'controller\.n: 100 is above the maximum'):
        load_scenario(CONFIG / 'ipdt_pid.yaml', ['controller.n=100.0'])
    scenario = standin_scenario(scenario_path, ('controller.n=100.0',))
    with pytest.raises(RunFailed, match='controller') as info:
        run_scenario(scenario, tmp_path / 'out', env=ros_env, node_command=standin_command)
    assert 'n: 100 is above the maximum' in str(info.value)


def test_another_graph_on_the_same_domain_is_refused_before_anything_starts(
        scenario_path, tmp_path, shared_ros_env, procs, probe):
    """A `reference` already running on this ROS_DOMAIN_ID (not started by tank-control) would
    answer our plant too: the run refuses before tick 0 and leaves no output directory."""
    foreign = procs.start('foreign', [*standin_command('reference'), '--ros-args', '-p',
                                      'step_value:=5.0'], env=shared_ros_env)
    assert probe.wait_for(lambda: 'reference' in probe.node.get_node_names(), 30), foreign.tail()
    out = tmp_path / 'out'
    with pytest.raises(RunFailed, match='another graph is running on ROS_DOMAIN_ID') as info:
        run_scenario(standin_scenario(scenario_path), out, env=shared_ros_env,
                     node_command=standin_command)
    assert 'reference' in str(info.value)
    assert not out.exists()
    assert foreign.returncode is None                     # and it is left alone


def test_a_foreign_clock_publisher_is_refused(scenario_path, tmp_path, shared_ros_env, probe):
    """Any node publishing a topic of the run (here /clock, as a simulator would) is another
    graph, whatever its name."""
    from rosgraph_msgs.msg import Clock
    probe.node.create_publisher(Clock, '/clock', 10)
    out = tmp_path / 'out'
    with pytest.raises(RunFailed, match=r'publisher of /clock \(test_probe'):
        run_scenario(standin_scenario(scenario_path), out, env=shared_ros_env,
                     node_command=standin_command)
    assert not out.exists()
