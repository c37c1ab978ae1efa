"""Shipped scenarios over the real ROS 2 graph (plant, controller, reference as separate
processes, recorder in the harness): the lockstep trace equals the in-process loop to 1e-9,
run.mcap opens with the mcap reader and holds the topics, and a representative claim holds
over ROS too. Durations are cut with --duration to keep CI short."""
from __future__ import annotations

import gc
import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from support import CONFIG
from support.mcap import read_mcap, stamps_and_arrivals

from tank_control.core.trace import Trace
from tank_control.harness.analysis_ahead import PART
from tank_control.harness.runner import run

SIGNAL_TOPICS = {'/measurement', '/setpoint', '/manipulated', '/disturbance', '/clock'}


def cli(*args: str, env=None, timeout: float = 600.0) -> subprocess.CompletedProcess:
    """`tank-control ARGS` to completion. Past ``timeout`` it is interrupted (SIGINT), so the
    harness stops its node processes instead of leaving them behind, and the test fails."""
    argv = [sys.executable, '-m', 'tank_control.harness.cli', *args]
    with subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True) as popen:
        try:
            stdout, stderr = popen.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            popen.send_signal(signal.SIGINT)
            stdout, stderr = popen.communicate(timeout=60)
            raise AssertionError(f'tank-control {" ".join(args)}: no end in {timeout:g} s\n'
                                 + stderr[-3000:]) from None
    return subprocess.CompletedProcess(argv, popen.returncode, stdout, stderr)


def assert_equal_traces(ros_csv: Path, in_process_csv: Path) -> None:
    ros, ref = Trace.read_csv(ros_csv), Trace.read_csv(in_process_csv)
    assert list(ros.columns) == list(ref.columns)
    assert len(ros) == len(ref)
    for name in ref.columns:
        np.testing.assert_allclose(ros.columns[name], ref.columns[name], rtol=0, atol=1e-9,
                                   err_msg=name)


def test_ipdt_lockstep_over_ros_equals_in_process_and_keeps_the_000_claim(tmp_path, ros_env):
    """Through the command line: [Viteckova] MDP PID 2-DOF (config/ipdt_pid.yaml), 200 s with the
    setpoint step at 10 s and the load step at 150 s."""
    scenario = str(CONFIG / 'ipdt_pid.yaml')
    ros = cli('run', scenario, '--out', str(tmp_path / 'ros'), '--duration', '200', env=ros_env)
    assert ros.returncode == 0, ros.stderr[-3000:]
    for key in ('plot:', 'trace:', 'recording:', 'metrics:'):
        assert key in ros.stdout
    ref = cli('run', scenario, '--out', str(tmp_path / 'ref'), '--duration', '200',
              '--in-process', '--no-plots', env=ros_env)
    assert ref.returncode == 0, ref.stderr[-3000:]
    assert_equal_traces(tmp_path / 'ros' / 'trace.csv', tmp_path / 'ref' / 'trace.csv')

    metrics = json.loads((tmp_path / 'ros' / 'metrics.json').read_text())
    assert metrics['mode'] == 'lockstep'
    assert metrics['run']['ticks'] == 2001
    assert metrics['run']['missed_samples'] == 0 and metrics['run']['late_samples'] == 0
    assert metrics['outputs']['y']['steps'][0]['overshoot_pct'] <= 3.0       # [Checks] §3
    gains = metrics['controller']['final_gains']                              # from the node
    assert round(gains['kp'], 2) == 3.13 and round(gains['b'], 2) == 0.42
    # the loop analysis, computed while the run went on (harness/analysis_ahead.py) for the
    # parameters the controller started and ended with, is the in-process run's
    in_process = json.loads((tmp_path / 'ref' / 'metrics.json').read_text())
    assert metrics['loop_analysis'] and metrics['loop_analysis'] == in_process['loop_analysis']
    assert (tmp_path / 'ros' / 'analysis.png').stat().st_size > 0
    assert not (tmp_path / 'ros' / PART).exists()

    topics = read_mcap(tmp_path / 'ros' / 'run.mcap')
    assert SIGNAL_TOPICS <= set(topics)
    assert len({m.header.stamp.nanosec + m.header.stamp.sec * 10**9
                for m in topics['/manipulated']}) >= 2001
    assert list(topics['/measurement'][0].name) == ['y']


def stamp_ns(msg) -> int:
    """A recorded message's stamp: ``header.stamp``, or a ``/clock`` message's time [ns]."""
    stamp = msg.clock if hasattr(msg, 'clock') else msg.header.stamp
    return stamp.sec * 10**9 + stamp.nanosec


def test_lockstep_beside_busy_loops_records_every_tick_equal_to_in_process(tmp_path, ros_env,
                                                                          procs):
    """The recorder is off the tick's serial path (the plant runs up to 8 ticks ahead of its
    acknowledgments): with two busy loops competing for the 2 cores, as fast as possible,
    every tick of every signal is in run.mcap and trace.csv, equal to the in-process loop (60 s:
    the setpoint step at 10 s and 600 ticks of the busy machine)."""
    for i in range(2):
        procs.start(f'busy{i}', [sys.executable, '-c', 'while 1: pass'])
    scenario = str(CONFIG / 'ipdt_pid.yaml')
    ros = cli('run', scenario, '--out', str(tmp_path / 'ros'), '--duration', '60', '--rtf', '0',
              '--no-plots', env=ros_env)
    assert ros.returncode == 0, ros.stderr[-3000:]
    ref = cli('run', scenario, '--out', str(tmp_path / 'ref'), '--duration', '60',
              '--in-process', '--no-plots', env=ros_env)
    assert ref.returncode == 0, ref.stderr[-3000:]
    assert_equal_traces(tmp_path / 'ros' / 'trace.csv', tmp_path / 'ref' / 'trace.csv')
    run_info = json.loads((tmp_path / 'ros' / 'metrics.json').read_text())['run']
    assert run_info['ticks'] == 601 and run_info['missed_samples'] == 0
    assert run_info['record_window'] == 8
    topics = read_mcap(tmp_path / 'ros' / 'run.mcap')
    ticks = {k * 100_000_000 for k in range(601)}
    for topic in ('/measurement', '/manipulated', '/clock'):
        stamps = {stamp_ns(m) for m in topics[topic]}
        assert ticks <= stamps, (topic, sorted(ticks - stamps)[:10])
    # The reference's topics: one message per change and a hold at least every
    # lockstep.lookahead (6) ticks (docs/nodes.md, "The reference"; the first hold, published
    # on /clock 1, is 7 ticks after tick 0's message): a lost one would leave a wider gap (or
    # a wrong value in the trace).
    for topic in ('/setpoint', '/disturbance'):
        stamps = sorted({stamp_ns(m) for m in topics[topic]})
        assert stamps[0] == 0 and stamps[-1] >= max(ticks), topic
        gaps = np.diff(stamps) // 100_000_000
        assert gaps[0] <= 7 and gaps[1:].max() <= 6 and len(stamps) < len(ticks) / 4, \
            (topic, gaps.max(), len(stamps))


def test_mixing_tank_lockstep_over_ros_equals_in_process(tmp_path, ros_env):
    """tank_pi_decoupled ([Michalski2021] two-loop PI with decoupling, delays of 180 s and 120 s):
    every signal of both outputs and inputs equal to 1e-9 over 1000 ticks."""
    scenario = CONFIG / 'scenarios' / 'tank_pi_decoupled.yaml'
    ros = run(scenario, tmp_path / 'ros', duration=1000.0, env=ros_env)
    ref = run(scenario, tmp_path / 'ref', duration=1000.0, in_process=True, plots=False)
    assert_equal_traces(ros.files['trace'], ref.files['trace'])
    assert ros.metrics['run']['missed_samples'] == 0
    assert ros.metrics['controller']['final_gains']['two_loop.ki_T'] == -0.01
    # the same finish as in-process: each loop's margins and analysis.png
    assert len(ros.metrics['loop_analysis']) == 4
    assert ros.metrics['loop_analysis'] == ref.metrics['loop_analysis']
    assert ros.files['analysis'].read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    # the harness froze its start-up objects for the run (runtime.quiet_collector) and gave
    # them back to the collector after it: a process running many runs keeps nothing
    assert gc.get_freeze_count() == 0
    topics = read_mcap(ros.files['recording'])
    assert SIGNAL_TOPICS <= set(topics)
    assert set(topics['/measurement'][0].name) == {'h', 'T_out'}
    assert set(topics['/manipulated'][0].name) == {'F_H', 'F_Cin'}


def test_fsa_on_the_unstable_plant_over_ros_equals_in_process(tmp_path, ros_env):
    """foupdt_fsa ([Precup2013] §3.6.2): controller_node runs the fsa kind on the unstable
    1/(10s − 1)·e^(−5s); the lockstep trace over the setpoint and the load step (120 s) equals
    the in-process one to 1e-9 and keeps the designed overshoot (4.60 %)."""
    scenario = CONFIG / 'scenarios' / 'foupdt_fsa.yaml'
    ros = run(scenario, tmp_path / 'ros', duration=120.0, env=ros_env, plots=False)
    ref = run(scenario, tmp_path / 'ref', duration=120.0, in_process=True, plots=False)
    assert_equal_traces(ros.files['trace'], ref.files['trace'])
    assert ros.metrics['run']['missed_samples'] == 0
    assert ros.metrics['outputs']['y']['steps'][0]['overshoot_pct'] == pytest.approx(4.60,
                                                                                     abs=0.01)
    assert ros.metrics['controller']['final_gains'] == {'fsa.omega0': 0.2, 'fsa.xi': 0.7}


def test_in_process_and_lockstep_report_the_same_controller_that_ran(tmp_path, ros_env):
    """fopdt_autotune_scheduled: the relay test at 60 s tunes the PID. Both runs report the values the
    controller ended with (the node's parameters; in-process the controller object's), not
    the file's: the same tuned gains, Ku, Tu and state in both metrics.json, and the same state
    changes at the same loop times (the ROS run's from the recorded /parameter_events), which
    plot.png marks."""
    scenario = CONFIG / 'scenarios' / 'fopdt_autotune_scheduled.yaml'
    ros = run(scenario, tmp_path / 'ros', rtf=0.0, env=ros_env)
    ref = run(scenario, tmp_path / 'ref', in_process=True, plots=False)
    assert_equal_traces(ros.files['trace'], ref.files['trace'])
    a, b = (r.metrics['controller'] for r in (ros, ref))
    assert a['autotune']['autotune.state'] == b['autotune']['autotune.state'] == 'running'
    assert a['final_gains']['kp'] != 20.0                      # not the file's kp
    for key in ('kp', 'ti', 'td', 'b', 'c'):
        assert a['final_gains'][key] == pytest.approx(b['final_gains'][key], rel=1e-9), key
    for key in ('autotune.ku', 'autotune.tu', 'autotune.model_gain', 'autotune.cycles'):
        assert a['autotune'][key] == pytest.approx(b['autotune'][key], rel=1e-9), key
    # the tuner changed the gains: the analysis made during the run is dropped, the final
    # gains' is the in-process run's
    assert ros.metrics['loop_analysis'] == ref.metrics['loop_analysis'] != {}
    assert ros.files['analysis'].exists() and not (tmp_path / 'ros' / PART).exists()
    states = ros.metrics['run']['controller_states']
    assert [s for _, s in states] == ['settling', 'relay', 'measuring', 'tuned', 'running']
    assert [list(s) for s in states] == [list(s) for s in ref.metrics['run']['controller_states']]


def test_transient_points_over_ros_equal_the_in_process_ones(tmp_path, ros_env):
    """fopdt_relay_transient ([Precup2013] eqs. 3.3.1–3.3.10), cut after the tuner took over (≈ 466 s):
    controller_node reports the same transient points (autotune.transient_omega/gain/phase,
    read-only parameters) and summary line as the in-process loop, on an equal trace."""
    scenario = CONFIG / 'scenarios' / 'fopdt_relay_transient.yaml'
    ros = run(scenario, tmp_path / 'ros', rtf=0.0, duration=480.0, env=ros_env, plots=False)
    ref = run(scenario, tmp_path / 'ref', duration=480.0, in_process=True, plots=False)
    assert_equal_traces(ros.files['trace'], ref.files['trace'])
    a, b = (r.metrics['controller'] for r in (ros, ref))
    assert a['autotune']['autotune.state'] == b['autotune']['autotune.state'] == 'running'
    assert len(a['autotune']['autotune.transient_omega']) == 5
    for key in ('autotune.transient_omega', 'autotune.transient_gain',
                'autotune.transient_phase'):
        assert a['autotune'][key] == pytest.approx(b['autotune'][key], rel=1e-9), key
    for key in ('autotune.transient_record', 'autotune.transient_alpha_used', 'autotune.ku'):
        assert a['autotune'][key] == pytest.approx(b['autotune'][key], rel=1e-9), key
    assert a['summary'] == b['summary'] and 'G(jω) from the transient' in a['summary']


def test_sim_mode_runs_on_the_simulated_clock(tmp_path, ros_env):
    """sim: the plant publishes /clock at 5x real time; the others answer each /clock tick.
    The plant starts paused and the harness releases it once the graph is up, so the
    recording holds every tick from t = 0."""
    result = run(CONFIG / 'ipdt_pid.yaml', tmp_path / 'sim', mode='sim', rtf=5.0, duration=30.0,
                 env=ros_env, plots=False)
    trace, run_info = result.trace, result.metrics['run']
    assert run_info['mode'] == 'sim'
    assert trace.t[0] == 0.0 and trace.t[-1] == pytest.approx(30.0, abs=1e-9)
    assert np.allclose(np.diff(trace.t), 0.1)                     # on the sim-time grid
    assert run_info['missed_samples'] == 0 and run_info['ticks'] == 301
    assert run_info['max_jitter'] < 1e-9
    # lateness is reported as in lockstep: per answer signal, summed
    assert set(run_info['late_by_signal']) == {'r', 'u', 'd'}
    assert run_info['late_samples'] == sum(run_info['late_by_signal'].values())


WALL_STEP = 1.5        # [s] of plant time


def test_wall_mode_setpoint_step_appears_at_its_time_on_the_plant_time_base(tmp_path, ros_env):
    """wall: the reference schedules on the plant's time origin (its tick 0), so a step
    scheduled at t = 1.5 s is in the trace at 1.5 s of plant time (within one sample), however
    much earlier or later than the plant the reference process started."""
    scenario = tmp_path / 'wall.yaml'
    scenario.write_text(json.dumps({   # JSON: strings quoted (an unquoted y is a boolean)
        'plant': {'ros__parameters': {'plant': 'ipdt', 'sample_time': 0.1, 'gain': 0.05,
                                      'dead_time': 0.5}},
        'controller': {'ros__parameters': {'controller': 'pid', 'sample_time': 0.1, 'kp': 2.0,
                                           'output_names': ['y'], 'input_names': ['u']}},
        'reference': {'ros__parameters': {'sample_time': 0.1, 'wall.lead': 0.05,
                                          'setpoint.channels': ['y'],
                                          'setpoint.y.times': [0.0, WALL_STEP],
                                          'setpoint.y.values': [0.0, 1.0]}},
        'harness': {'ros__parameters': {'duration': 3.0, 'clock_mode': 'wall',
                                        'startup_timeout': 60.0}}}))
    result = run(scenario, tmp_path / 'out', env=ros_env, plots=False)
    trace, run_info = result.trace, result.metrics['run']
    # plant time: tick 0 (held until the graph was up) is t = 0; rows a whole number of ticks
    # apart (one, unless the plant's timer skipped a period: counted in missed_samples)
    ticks = np.diff(trace.t) / 0.1
    assert trace.t[0] == 0.0 and np.allclose(ticks, np.round(ticks), atol=1e-6)
    assert np.all(np.round(ticks) >= 1)
    assert run_info['missed_samples'] == int(np.sum(np.round(ticks) - 1))
    r = trace.columns['r.y']
    first = trace.t[np.flatnonzero(r == 1.0)[0]]
    assert WALL_STEP - 1e-9 <= first <= WALL_STEP + 0.1 + 1e-9, first
    assert not np.any(r[trace.t < WALL_STEP - 1e-9] == 1.0)
    # ... and the controller acted on it at its instant: the setpoint, published wall.lead
    # ahead, was there before the measurement of that instant (before the lead, the step
    # acted one sample late and every setpoint was reported late)
    u = trace.columns['u.u']            # kp·(r − y): 0 while r = y = 0 (NaN before the first)
    assert trace.t[np.flatnonzero(u > 0.0)[0]] == pytest.approx(first, abs=1e-9)
    # ... every setpoint the reference published in time was in time at the controller: late
    # are at most those that reached the recorder only after their instant (a reference whose
    # timer fired more than wall.lead late on a loaded machine: 1 in 30 runs beside two busy
    # lockstep graphs)
    published_late = sum(arrived >= stamp for stamp, arrived in
                         stamps_and_arrivals(tmp_path / 'out' / 'run.mcap', 'setpoint'))
    assert run_info['late_by_signal']['r'] <= published_late
    # ... from tick 0 on: the plant announced its origin ahead (plant_node.ORIGIN_NOTICE_S), so
    # the reference's instant 0 was there before measurement 0 (announced at tick 0, the origin
    # raced measurement 0: the controller skipped tick 0 in about half the runs, and a
    # reference that heard the origin more than wall.lead late never published instant 0)
    assert u[0] == 0.0
    assert run_info['late_samples'] == sum(run_info['late_by_signal'].values())


def test_a_reader_that_never_matches_delays_a_wall_start_by_a_bounded_wait(tmp_path, ros_env,
                                                                          probe):
    """Before tick 0 the harness waits for the plant to match every endpoint the graph shows,
    and the plant for those of its own view (``MATCH_WAIT_S`` each). A reader that never
    matches — here a transient-local reader of the volatile measurement, as a misconfigured
    tool would be — ends both waits, not the run: it completes from tick 0 and the plant's
    log names the topic."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    probe.node.create_subscription(
        JointState, 'measurement', lambda m: None,
        QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    scenario = tmp_path / 'wall.yaml'
    scenario.write_text(json.dumps({
        'plant': {'ros__parameters': {'plant': 'ipdt', 'sample_time': 0.1, 'gain': 0.05}},
        'controller': {'ros__parameters': {'controller': 'pid', 'sample_time': 0.1, 'kp': 2.0,
                                           'output_names': ['y'], 'input_names': ['u']}},
        'reference': {'ros__parameters': {'sample_time': 0.1, 'setpoint.channels': ['y'],
                                          'setpoint.y.times': [0.0], 'setpoint.y.values': [1.0]}},
        'harness': {'ros__parameters': {'duration': 1.0, 'clock_mode': 'wall',
                                        'startup_timeout': 60.0}}}))
    result = run(scenario, tmp_path / 'out', env=ros_env, plots=False)
    assert result.trace.t[0] == 0.0 and result.trace.t[-1] >= 0.9
    log = (tmp_path / 'out' / 'logs' / 'plant.log').read_text()
    assert 'measurement not matched' in log, log


@pytest.mark.slow
def test_compare_writes_a_table_and_an_overlay(tmp_path):
    out = tmp_path / 'cmp'
    done = cli('compare', str(CONFIG / 'scenarios' / 'ipdt_mdp_pi.yaml'),
               str(CONFIG / 'scenarios' / 'ipdt_mdp_pi_1dof.yaml'),
               '--in-process', '--quiet', '--out', str(out))
    assert done.returncode == 0, done.stderr
    table = (out / 'comparison.md').read_text()
    assert '| ipdt_mdp_pi | y |' in table and '| ipdt_mdp_pi_1dof | y |' in table
    assert (out / 'overlay.png').read_bytes()[:4] == b'\x89PNG'
    assert (out / 'ipdt_mdp_pi' / 'metrics.json').exists()


@pytest.mark.parametrize('args, words', [
    (['--set', 'controller.kp'], 'NODE.PARAM=VALUE'),
    (['--set', 'harness.clock_mode=fast'], 'clock_mode'),
    (['--mode', 'sim'], 'real_time_factor'),
    (['--set', 'controller.tuning.rule=nonsense', '--in-process'], 'tuning.rule'),
])
def test_bad_command_lines_exit_2_with_a_reason(tmp_path, args, words):
    done = cli('run', str(CONFIG / 'ipdt_pid.yaml'), '--out', str(tmp_path), *args)
    assert done.returncode == 2
    assert words in done.stderr and len(done.stderr.strip().splitlines()) == 1


def test_progress_is_a_rewritten_line_on_a_terminal_and_plain_lines_in_ci():
    import io

    from tank_control.harness.cli import ProgressPrinter
    from tank_control.harness.runner import Progress

    steps = [Progress(s, 100.0, 50.0, 500.0, (100.0 - s) / 50.0) for s in (0, 5, 12, 13, 100)]
    tty, plain = io.StringIO(), io.StringIO()
    for p in steps:
        ProgressPrinter(tty, 'x', tty=True)(p)
    printer = ProgressPrinter(plain, 'x', tty=False)
    for p in steps:
        printer(p)
    assert tty.getvalue().count('\r') == 5 and 'ETA' in tty.getvalue()
    lines = plain.getvalue().splitlines()
    assert len(lines) == 3                                 # 0 %, 10 % decile, 100 %
    assert lines[-1].startswith('x: sim 100.0/100 s, 50.0x real time, 500 ticks/s')


@pytest.mark.parametrize('name', ['tank_pi_feedforward_dynamic', 'tank_pi_scheduled'])
def test_scheduled_and_feedforward_tank_lockstep_over_ros_equals_in_process(tmp_path, ros_env,
                                                                            name):
    """The two-loop PI with dynamic feedforward (controller_node reads F_D, T_D from the
    disturbance topic; the F_D step at 100 s and the 180 s bridge) and with gains scheduled
    on the level (h 81 → 40 cm from 100 s): the lockstep trace equals the in-process one to
    1e-9 over 700 ticks."""
    scenario = CONFIG / 'scenarios' / f'{name}.yaml'
    ros = run(scenario, tmp_path / 'ros', duration=700.0, env=ros_env, plots=False)
    ref = run(scenario, tmp_path / 'ref', duration=700.0, in_process=True, plots=False)
    assert_equal_traces(ros.files['trace'], ref.files['trace'])
    assert ros.metrics['run']['missed_samples'] == 0
    columns = ref.trace.columns
    if name == 'tank_pi_scheduled':
        assert columns['y.h'][-1] < 60.0                    # the gains did move with h
    else:
        assert np.max(np.abs(columns['y.T_out'] - columns['r.T_out'])) < 0.02
