"""Nothing lost, nothing left running, no silent failure.

* the node processes die with the harness, whatever ends it (SIGTERM, SIGHUP: a clean stop;
  SIGKILL: the kernel's parent-death signal), and the next run on the domain works;
* a stopped or failed run leaves its trace, recording and metrics (``"complete": false``);
* a second run on a domain in use refuses before it touches anything and leaves the first
  alone;
* a run that records nothing fails;
* the recording streams: memory does not grow with the messages.

Processes a test starts run in their own process groups; every wait is for an event (a
message on the graph, a line of output, a process's end through a pidfd) with a deadline.
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support import CONFIG
from support.mcap import read_mcap
from support.procfs import processes_with
from support.standins import SCENARIO, standin_command, standin_scenario

from tank_control.core.scenario import run_in_process
from tank_control.core.trace import Trace
from tank_control.harness.recording import RawMessage
from tank_control.harness.runner import RunFailed, run, run_scenario
from tank_control.harness.trace import SignalMessage, from_messages

HARNESS = [sys.executable, '-m', 'tank_control.harness.cli', 'run']
SIGNALS = {'SIGTERM': signal.SIGTERM, 'SIGHUP': signal.SIGHUP, 'SIGKILL': signal.SIGKILL}


# ------------------------------------------------------------------------------------ helpers
def wait_gone(pids: list[int], timeout: float) -> list[int]:
    """Wait (on pidfds: the kernel says when a process ends) until every process of ``pids``
    has ended; return those still running after ``timeout`` seconds."""
    fds = {}
    for pid in pids:
        try:
            fds[os.pidfd_open(pid)] = pid
        except ProcessLookupError:
            pass
    poller = select.poll()
    for fd in fds:
        poller.register(fd, select.POLLIN)
    deadline = time.monotonic() + timeout
    try:
        while fds:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            for fd, _ in poller.poll(remaining * 1000):
                poller.unregister(fd)
                os.close(fd)
                fds.pop(fd)
        return sorted(fds.values())
    finally:
        for fd in fds:
            os.close(fd)


def kill_all(pids: list[int]) -> None:
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def wait_for_stamp(probe, seconds: float, timeout: float = 300.0) -> int:
    """Wait until a measurement stamped at or after ``seconds`` is seen; return its stamp."""
    from sensor_msgs.msg import JointState

    from tank_control.nodes.messages import SIGNAL_QOS, stamp_to_ns
    latest = [-1]

    def seen(msg: JointState) -> None:
        latest[0] = max(latest[0], stamp_to_ns(msg.header.stamp))
    sub = probe.node.create_subscription(JointState, 'measurement', seen, SIGNAL_QOS)
    try:
        assert probe.wait_for(lambda: latest[0] >= seconds * 1e9, timeout), latest
    finally:
        probe.node.destroy_subscription(sub)
    return latest[0]


def wait_for_rows(path: Path, rows: int, timeout: float = 300.0) -> None:
    """Poll ``path`` (a trace.csv being written) until it holds ``rows`` rows after its
    header, or fail at the deadline."""
    deadline = time.monotonic() + timeout
    while True:
        lines = path.read_bytes().count(b'\n') if path.exists() else 0
        if lines >= rows + 1:
            return
        assert time.monotonic() < deadline, f'{path}: {lines} lines after {timeout} s'
        time.sleep(0.05)                       # polling a file: there is no event to await


def assert_prefix_of_in_process_run(out: Path) -> Trace:
    """trace.csv of ``out`` equals the in-process loop of its scenario.yaml, row by row, for as
    many rows as it has (lockstep == in-process to 1e-9): nothing mixed in, nothing lost."""
    trace = Trace.read_csv(out / 'trace.csv')
    assert len(trace) >= 1
    np.testing.assert_allclose(np.diff(trace.t), 0.1, rtol=0, atol=1e-9)   # no tick missing
    expected = run_in_process(out / 'scenario.yaml', duration=float(trace.t[-1]))
    assert len(expected) == len(trace) and trace.names == expected.names
    worst = trace.max_abs_difference(expected)
    assert max(worst.values()) <= 1e-9, worst
    return trace


def short_run(out: Path, env) -> dict:
    """A short lockstep run of config/ipdt_pid.yaml that must complete."""
    result = run(CONFIG / 'ipdt_pid.yaml', out, duration=3.0, env=env, plots=False)
    assert result.metrics['complete'] is True and result.metrics['reason'] is None
    trace = assert_prefix_of_in_process_run(out)
    assert len(trace) == 31 and trace.t[0] == 0.0
    return result.metrics


# --------------------------------------------------------------------------- nodes die with it
def test_a_started_process_dies_when_its_starter_is_killed(tmp_path):
    """SIGKILL gives the harness no chance to stop anything: the kernel ends its children."""
    starter = subprocess.Popen(
        [sys.executable, '-c',
         'import sys, time\n'
         'from tank_control.harness.processes import ProcessGroup\n'
         f'group = ProcessGroup({str(tmp_path)!r})\n'
         'child = group.start("sleeper", [sys.executable, "-c", "import time; time.sleep(600)"])\n'
         'print(child.popen.pid, flush=True)\n'
         'time.sleep(600)\n'],
        stdout=subprocess.PIPE, text=True, start_new_session=True)
    child = None
    try:
        child = int(starter.stdout.readline())
        assert wait_gone([child], 0.5) == [child]            # it runs while its starter does
        starter.kill()
        starter.wait()
        assert wait_gone([child], 60) == []
    finally:
        starter.kill()
        starter.wait()
        if child is not None:
            kill_all([child])


@pytest.mark.parametrize('name', SIGNALS)
def test_killing_the_harness_leaves_no_node_running_and_the_next_run_works(
        name, tmp_path, procs, ros_env, probe):
    sig = SIGNALS[name]
    out = tmp_path / 'a'
    harness = procs.start('harness', [*HARNESS, str(CONFIG / 'ipdt_pid.yaml'), '--out', str(out),
                                      '--duration', '3000', '--quiet', '--no-plots'], env=ros_env)
    wait_for_stamp(probe, 2.0)
    wait_for_rows(out / 'trace.csv', 10)        # rows are on disk while the run goes
    nodes = processes_with(str(out / 'scenario.yaml'))
    try:
        assert len(nodes) == 3, (nodes, harness.tail())
        os.kill(harness.popen.pid, sig)
        harness.popen.wait(timeout=120)
        assert wait_gone(nodes, 60) == []
    finally:
        kill_all(nodes)
    code = harness.popen.returncode
    if sig == signal.SIGKILL:                   # no chance to finish: the rows on disk stay
        assert code == -signal.SIGKILL
        assert not (out / 'metrics.json').exists()
        assert len(assert_prefix_of_in_process_run(out)) >= 10
    else:                                       # a clean stop: what was recorded is kept
        assert code == 128 + sig, harness.tail()
        assert f'interrupted by {name}' in harness.tail()
        assert f'the results so far are in {out} ("complete": false)' in harness.tail()
        metrics = json.loads((out / 'metrics.json').read_text())
        assert metrics['complete'] is False and metrics['reason'] == f'interrupted by {name}'
        trace = assert_prefix_of_in_process_run(out)
        assert trace.t[-1] >= 2.0 - 0.1 and metrics['run']['ticks'] == len(trace)
        recorded = read_mcap(out / 'run.mcap')
        assert len(recorded['/measurement']) >= len(trace)
    # The domain is free again at once: the killed run's nodes do not refuse the next one.
    short_run(tmp_path / 'b', ros_env)


def test_back_to_back_runs_on_one_domain_both_complete(tmp_path, ros_env):
    short_run(tmp_path / 'a', ros_env)
    short_run(tmp_path / 'b', ros_env)


# ------------------------------------------------------------------------- one run per domain
def test_a_second_run_refuses_at_once_and_leaves_the_first_untouched(tmp_path, procs, ros_env,
                                                                     probe):
    first = tmp_path / 'first'
    harness = procs.start('harness', [*HARNESS, str(CONFIG / 'ipdt_pid.yaml'), '--out',
                                      str(first), '--duration', '3000', '--quiet', '--no-plots'],
                             env=ros_env)
    wait_for_stamp(probe, 1.0)
    second = tmp_path / 'second'
    with pytest.raises(RunFailed, match='in use by another tank-control run on this host') as info:
        run(CONFIG / 'ipdt_pid.yaml', second, duration=5.0, env=ros_env)
    assert str(first.resolve()) in str(info.value)
    assert not second.exists()
    # The first goes on, undisturbed, and stops cleanly on SIGINT.
    at_refusal = wait_for_stamp(probe, 0.0)
    wait_for_stamp(probe, at_refusal / 1e9 + 2.0)
    nodes = processes_with(str(first / 'scenario.yaml'))
    os.kill(harness.popen.pid, signal.SIGINT)
    assert harness.popen.wait(timeout=120) == 130, harness.tail()
    assert wait_gone(nodes, 60) == []
    metrics = json.loads((first / 'metrics.json').read_text())
    assert metrics['reason'] == 'interrupted by SIGINT'
    trace = assert_prefix_of_in_process_run(first)
    # every tick seen after the refusal is in it but the last (its answers may not have come)
    assert trace.t[-1] >= at_refusal / 1e9 + 2.0 - 0.1 - 1e-9


class _Graph:
    """A node's view of the graph for ``foreign_graph``: the names and publishers it sees,
    and how often it was spun (each spin a wall-time wait in a real node)."""

    def __init__(self, names=(), publishers=None) -> None:
        self.names = [('graph_look', '/'), *((name, '/') for name in names)]
        self.publishers = publishers or {}
        self.spins = 0

    def get_name(self) -> str:
        return 'graph_look'

    def get_node_names_and_namespaces(self):
        return self.names

    def get_publishers_info_by_topic(self, topic):
        return [type('Info', (), {'node_name': node})() for node in self.publishers.get(topic, ())]

    def spin_once(self, timeout: float) -> None:
        self.spins += 1


def test_the_graph_look_counts_the_time_since_the_participant_joined():
    """Discovery runs in DDS's own threads from the moment the participant joins: time the
    harness spent on other work since then is part of the look, which then only looks."""
    from tank_control.harness.graph_check import foreign_graph
    empty = _Graph()
    joined = time.monotonic() - 10.0
    assert foreign_graph(empty, empty.spin_once, ['measurement'], 4.0, since=joined) is None
    assert empty.spins == 0
    running = _Graph(['plant'], {'/measurement': ['plant']})
    found = foreign_graph(running, running.spin_once, ['measurement'], 4.0, since=joined)
    assert found == 'node plant; publisher of /measurement (plant)'


def test_the_look_while_the_nodes_start_tells_them_from_another_graph():
    """The run's own nodes, coming up meanwhile, are not another graph: a name this run
    started seen once, and its publishers, are its own; a second node of the name or a
    publisher of a node it did not start is another graph's. The look lasts until the run's
    nodes are up (``ready``)."""
    from tank_control.harness.graph_check import foreign_graph
    joined = time.monotonic() - 10.0
    started = ('plant', 'controller', 'reference')
    own = _Graph(started, {'/measurement': ['plant'], '/manipulated': ['controller']})
    assert foreign_graph(own, own.spin_once, ['measurement', 'manipulated'], 4.0, since=joined,
                         started=started) is None
    twice = _Graph((*started, 'reference'), {'/setpoint': ['reference']})
    assert foreign_graph(twice, twice.spin_once, ['setpoint'], 4.0, since=joined,
                         started=started) == 'node reference; publisher of /setpoint (reference)'
    other = _Graph(started, {'/clock': ['plant', 'gazebo']})
    assert foreign_graph(other, other.spin_once, ['/clock'], 4.0, since=joined,
                         started=started) == 'publisher of /clock (gazebo)'
    up = iter([False, False, True])
    waiting = _Graph(started)
    assert foreign_graph(waiting, waiting.spin_once, ['measurement'], 0.0, since=joined,
                         started=started, ready=lambda: next(up)) is None
    assert waiting.spins == 2


# ------------------------------------------------------------------------------ no silent end
def test_a_run_that_records_nothing_fails(tmp_path, ros_env):
    """A plant whose clock is already beyond the duration (as a left-over plant of another run
    would be): nothing of the run's 6 s is recorded, which is a failure, not a success."""
    path = tmp_path / 'standin.yaml'
    path.write_text(SCENARIO)
    out = tmp_path / 'out'
    with pytest.raises(RunFailed, match='holds no measurement within the 6 s'):
        run_scenario(standin_scenario(path, ('plant.first_tick=1000',)), out, env=ros_env,
                     node_command=standin_command)
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['complete'] is False and metrics['run']['ticks'] == 0
    assert Trace.read_csv(out / 'trace.csv').names == ('t',)


def test_an_in_process_run_stopped_by_sigterm_keeps_its_rows(tmp_path):
    out = tmp_path / 'out'
    proc = subprocess.Popen([*HARNESS, str(CONFIG / 'ipdt_pid.yaml'), '--out', str(out),
                             '--in-process', '--duration', '300000', '--no-plots'],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, env={**os.environ, 'CI': '1'})
    try:
        first = proc.stderr.readline()          # the first progress line: rows are being written
        assert 'ticks/s' in first, first
        proc.send_signal(signal.SIGTERM)
        rest = proc.communicate(timeout=300)[1]
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 143, rest
    assert 'interrupted by SIGTERM' in rest
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['complete'] is False and metrics['reason'] == 'interrupted by SIGTERM'
    trace = assert_prefix_of_in_process_run(out)
    assert 0 < len(trace) < 3_000_001 and metrics['run']['ticks'] == len(trace)
    assert len(read_mcap(out / 'run.mcap')['/measurement']) == len(trace)


# ----------------------------------------------------------------------- streaming recording
def _lockstep_raw(k: int, ts_ns: int = 100_000_000) -> list[RawMessage]:
    """Tick k of a lockstep run as the recorder receives it (serialized JointStates)."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    out = []
    for topic, names, values in (('measurement', ['y'], [0.5 * k]), ('setpoint', ['y'], [1.0]),
                                 ('manipulated', ['u'], [2.0 - k]), ('disturbance', ['v'], [0.0])):
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * ts_ns, 1_000_000_000)
        msg.name, msg.position = names, [float(v) for v in values]
        out.append(RawMessage('/' + topic, 'sensor_msgs/msg/JointState', serialize_message(msg),
                              k, k * ts_ns))
    return out


def _stream(out: Path, ticks: int, clock: list[float]) -> tuple[Any, list]:
    from tank_control.harness.stream import RecordingStream
    out.mkdir()
    stream = RecordingStream(out, lambda: 0, None, 100_000_000, {'u': 200_000_000},
                             0.1, holdback=2.0, clock=lambda: clock[0])
    signals = []
    for k in range(ticks):
        for raw in _lockstep_raw(k):
            stream.on_message(raw)
            if k < 50:
                from tank_control.harness.recorder import signal_message
                signals.append(signal_message(raw))
        clock[0] += 0.01                      # 100 ticks per wall second
        stream.advance()
    return stream, signals


@pytest.mark.slow
def test_the_recording_streams_with_bounded_memory(tmp_path):
    """Messages go to run.mcap and rows to trace.csv as they come: what stays in memory is the
    table (8 bytes per value: 5 columns here) and a couple of seconds of messages."""
    _stream(tmp_path / 'warm-up', 300, [0.0])[0].close()   # imports and caches: not growth
    peaks = {}
    for ticks in (1_000, 4_000):
        clock = [0.0]
        tracemalloc.start()
        stream, _ = _stream(tmp_path / str(ticks), ticks, clock)
        trace = stream.close()
        peaks[ticks] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert len(trace) == ticks
    growth = (peaks[4_000] - peaks[1_000]) / 3_000
    assert growth < 200, f'{growth:.0f} bytes per tick'       # ≥ 1.6 kB per tick when kept


def test_rows_are_written_as_the_run_goes_and_equal_the_join_of_everything(tmp_path):
    clock = [0.0]
    stream, signals = _stream(tmp_path / 'run', 50, clock)
    # 0.5 s of wall time (50 ticks) < the 2 s holdback: nothing is written yet ...
    assert len(stream.outputs.trace) == 0
    clock[0] += 2.0
    stream.advance()
    # ... and then every row that a later measurement closes (the last one waits for the end).
    assert len(stream.outputs.trace) == 49
    assert Trace.read_csv(tmp_path / 'run' / 'trace.csv').names == ('t', 'y.y', 'r.y', 'u.u', 'd.v')
    # A message for a row already written cannot change it: it is counted.
    stream.on_message(_lockstep_raw(3)[2])
    assert stream.joiner.after_written == 0            # the same message again: a repetition
    trace = stream.close()
    expected = from_messages(signals, 0, None, 100_000_000, {'u': 200_000_000})
    assert trace.max_abs_difference(expected) == {name: 0.0 for name in expected.names}
    assert trace.late == expected.late == {'r': 0, 'u': 0, 'd': 0}
    assert Trace.read_csv(tmp_path / 'run' / 'trace.csv').max_abs_difference(expected) == \
        {name: 0.0 for name in expected.names}


def test_a_late_message_for_a_written_row_is_counted(tmp_path):
    clock = [0.0]
    stream, _ = _stream(tmp_path / 'run', 10, clock)
    clock[0] += 5.0
    stream.advance()
    late = SignalMessage('manipulated', 300_000_000, ('u',), (99.0,))
    stream.joiner.add(late)
    assert stream.joiner.after_written == 1
    assert stream.close().columns['u.u'][3] == 2.0 - 3


def test_an_incomplete_run_leaves_out_the_row_whose_answers_never_came(tmp_path):
    """Stopped after the measurement of tick 10 and before its answers: rows 0 … 9 are whole
    (a lockstep plant publishes tick k + 1 only after the answers to tick k), row 10 is not
    written with a held value in place of the missing answer."""
    clock = [0.0]
    stream, _ = _stream(tmp_path / 'run', 10, clock)
    stream.on_message(_lockstep_raw(10)[0])             # measurement only
    trace = stream.close(complete=False)
    assert len(trace) == 10 and trace.t[-1] == pytest.approx(0.9, abs=1e-12)
    assert list(trace.columns['u.u']) == [2.0 - k for k in range(10)]
    assert len(Trace.read_csv(tmp_path / 'run' / 'trace.csv')) == 10


def test_an_incomplete_run_leaves_out_a_row_whose_answer_the_next_tick_overtook(tmp_path):
    """The plant's tick 10 reached the recorder before the controller's answer to tick 9 (two
    publishers, two paths), then the run stopped: row 9 is not written with tick 8's output."""
    clock = [0.0]
    stream, _ = _stream(tmp_path / 'run', 9, clock)
    measurement, setpoint, _manipulated, disturbance = _lockstep_raw(9)
    for raw in (measurement, setpoint, disturbance, _lockstep_raw(10)[0]):
        stream.on_message(raw)
    trace = stream.close(complete=False)
    assert len(trace) == 9 and trace.t[-1] == pytest.approx(0.8, abs=1e-12)
    assert list(trace.columns['u.u']) == [2.0 - k for k in range(9)]


# ------------------------------------------------------------------- a hard kill, then recover
RECOVER = [sys.executable, '-m', 'tank_control.harness.cli', 'recover']


@pytest.mark.parametrize('kill_at', [5.0, 12.0])
def test_a_hard_kill_loses_at_most_the_last_second_and_recover_makes_it_readable(
        kill_at, tmp_path, procs, ros_env, probe):
    """SIGKILL of the harness ``kill_at`` seconds into a real-time lockstep run (simulated time
    = run time), then ``tank-control recover``: mcap's standard reader (``make_reader`` with the
    ROS 2 decoder) reads every message up to the kill minus at most one second, and metrics.json
    says the run is not complete and why. The nodes die with the harness."""
    out = tmp_path / 'run'
    harness = procs.start('harness', [*HARNESS, str(CONFIG / 'ipdt_pid.yaml'), '--out', str(out),
                                      '--duration', '3000', '--rtf', '1', '--quiet'], env=ros_env)
    seen = wait_for_stamp(probe, kill_at) / 1e9      # published before the kill [s]
    nodes = processes_with(str(out / 'scenario.yaml'))
    try:
        assert len(nodes) == 3, (nodes, harness.tail())
        os.kill(harness.popen.pid, signal.SIGKILL)
        assert harness.popen.wait(timeout=120) == -signal.SIGKILL
        assert wait_gone(nodes, 60) == []
    finally:
        kill_all(nodes)
    assert not (out / 'metrics.json').exists()
    done = subprocess.run([*RECOVER, str(out)], capture_output=True, text=True, check=False, timeout=300)
    assert done.returncode == 0, done.stderr
    assert 'recovered' in done.stdout and '"complete": false' in done.stdout, done.stdout
    recorded = read_mcap(out / 'run.mcap')

    def stamps(topic: str) -> list[float]:       # a tick re-sent (tick 0 until held) once
        times = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in recorded[topic]]
        assert times == sorted(times)
        return sorted(set(times))
    ticks = stamps('/measurement')
    np.testing.assert_allclose(ticks, 0.1 * np.arange(len(ticks)), rtol=0, atol=1e-9)
    assert ticks[-1] >= seen - 1.0, (ticks[-1], seen)
    assert stamps('/manipulated')[:len(ticks) - 1] == ticks[:-1]      # each tick's answer
    assert len(recorded['/clock']) >= len(ticks) - 1 and recorded['/setpoint']
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['complete'] is False and 'recovered from run.mcap' in metrics['reason']
    assert metrics['scenario'] == 'ipdt_pid' and metrics['mode'] == 'lockstep'
    trace = assert_prefix_of_in_process_run(out)
    assert trace.t[-1] >= seen - 1.0 - 0.1 - 1e-9 and metrics['run']['ticks'] == len(trace)
    assert 'iae' in metrics['outputs']['y'] and (out / 'plot.png').exists()


def _cut_recording(path: Path, messages: int, flush_every: int) -> list[int]:
    """Write ``messages`` ticks' messages to ``path``, flushing every ``flush_every`` ticks;
    return the file size after each flush (where a kill would leave it whole)."""
    from tank_control.harness.recording import McapRecording
    sizes = []
    recording = McapRecording(path, {'scenario': 'cut', 'mode': 'lockstep'})
    for k in range(messages):
        for raw in _lockstep_raw(k):
            recording.add(raw)
        if (k + 1) % flush_every == 0:
            recording.flush()
            sizes.append(path.stat().st_size)
    recording._handle.close()                 # as a kill leaves it: no summary
    return sizes


def test_a_recording_cut_anywhere_keeps_every_flushed_message(tmp_path):
    """Cut at any byte after a flush, the file still gives every message flushed before it, in
    order, and nothing that was not whole; a damaged chunk is skipped, later ones are kept."""
    from tank_control.harness.recover import read_partial
    full = tmp_path / 'full.mcap'
    sizes = _cut_recording(full, 100, 10)
    data = full.read_bytes()
    cut = tmp_path / 'cut.mcap'
    for flushed, size in enumerate(sizes, start=1):
        for extra in (0, 1, 9, 200):
            cut.write_bytes(data[:size + extra])
            found = read_partial(cut)
            ticks = [raw.publish_time_ns for raw in found.messages if raw.topic == '/measurement']
            assert ticks == [k * 100_000_000 for k in range(10 * flushed)], (size, extra)
            assert found.metadata == {'scenario': 'cut', 'mode': 'lockstep'}
            assert not found.finished and found.read == size
    damaged = bytearray(data)
    middle = sizes[4] + 200                   # inside the sixth chunk's compressed data
    damaged[middle:middle + 4] = b'\0\0\0\0'
    cut.write_bytes(bytes(damaged))
    found = read_partial(cut)
    assert found.bad_chunks == 1
    ticks = [raw.publish_time_ns // 100_000_000 for raw in found.messages
             if raw.topic == '/measurement']
    assert ticks == [*range(50), *range(60, 100)]
    empty = tmp_path / 'empty.mcap'           # killed before the recording started
    empty.write_bytes(b'')
    found = read_partial(empty)
    assert found.messages == [] and found.stopped == 'empty file'


def test_recover_refuses_what_is_not_a_killed_run(tmp_path):
    done = subprocess.run([*RECOVER, str(tmp_path)], capture_output=True, text=True, check=False, timeout=120)
    assert done.returncode == 2 and 'not the output directory of a run' in done.stderr
    out = tmp_path / 'done'
    run(CONFIG / 'ipdt_pid.yaml', out, duration=2.0, in_process=True, plots=False)
    done = subprocess.run([*RECOVER, str(out)], capture_output=True, text=True, check=False, timeout=120)
    assert done.returncode == 2 and 'nothing to recover' in done.stderr, done.stderr
    assert json.loads((out / 'metrics.json').read_text())['complete'] is True   # untouched


# ---------------------------------------------------------------- a node that dies in the run
def _kill_controller_mid_run(tmp_path, procs, ros_env, probe, *settings: str):
    import rclpy
    """A lockstep run at 5x real time whose controller process is killed (SIGKILL) at 10 s
    of it, while a node the harness did not start joins the domain; returns the harness's
    exit code, its output and the output directory."""
    out = tmp_path / 'run'
    harness = procs.start('harness', [*HARNESS, str(CONFIG / 'ipdt_pid.yaml'), '--out', str(out),
                                      '--duration', '60', '--rtf', '5', '--quiet', '--no-plots',
                                      *(f'--set={s}' for s in settings)], env=ros_env)
    wait_for_stamp(probe, 10.0)
    intruder = rclpy.create_node(f'intruder_{os.getpid()}')      # on the session's domain
    try:
        controllers = [pid for pid in processes_with(str(out / 'scenario.yaml'))
                       if 'controller_node' in Path(f'/proc/{pid}/cmdline').read_text()]
        assert len(controllers) == 1, harness.tail()
        os.kill(controllers[0], signal.SIGKILL)
        code = harness.popen.wait(timeout=600)
    finally:
        intruder.destroy_node()
    return code, harness.tail(40), out


def test_a_controller_killed_mid_run_is_restarted_and_the_run_keeps_every_tick(
        tmp_path, procs, ros_env, probe):
    """``harness.on_node_exit: restart``: the controller's process is killed in a lockstep run;
    the harness starts it again with its parameters, it takes over on the running loop
    (docs/nodes.md, "Restarts"), and the run completes with every tick recorded and answered.
    The restart is in metrics.json, in run.mcap and in a warning, so is the node that joined."""
    code, tail, out = _kill_controller_mid_run(tmp_path, procs, ros_env, probe,
                                               'harness.on_node_exit=restart')
    assert code == 0, tail
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['complete'] is True
    run_info = metrics['run']
    [restart] = run_info['restarts']
    assert restart['node'] == 'controller' and restart['exit_code'] == -signal.SIGKILL
    assert restart['attempt'] == 1 and restart['time'] >= 10.0
    assert 'node controller exited with code -9' in tail and 'was restarted' in tail
    trace = Trace.read_csv(out / 'trace.csv')
    assert len(trace) == 601 and run_info['missed_samples'] == 0
    np.testing.assert_allclose(np.diff(trace.t), 0.1, rtol=0, atol=1e-9)
    assert np.isfinite(trace.columns['u.u']).all() and run_info['late_samples'] == 0
    # up to the kill the loop is the in-process one; after it the new controller answers
    expected = run_in_process(out / 'scenario.yaml', duration=60.0)
    before = round(restart['time'] / 0.1) - 1
    np.testing.assert_allclose(trace.columns['u.u'][:before], expected.columns['u.u'][:before],
                               rtol=0, atol=1e-9)
    recorded = read_mcap(out / 'run.mcap')
    [event] = recorded['/harness/events']
    assert 'node controller exited with code -9' in event.msg and 'restarted' in event.msg
    foreign = {n['node']: n for n in run_info['foreign_nodes']}
    assert f'intruder_{os.getpid()}' in foreign, foreign
    assert foreign[f'intruder_{os.getpid()}']['first_seen'] >= 10.0
    assert 'did not start' in tail and f'intruder_{os.getpid()}' in tail


def test_a_controller_killed_mid_run_ends_the_run_by_default(tmp_path, procs, ros_env, probe):
    code, tail, out = _kill_controller_mid_run(tmp_path, procs, ros_env, probe)
    assert code == 1, tail
    assert 'run failed: node controller exited with code -9 during the run' in tail
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['complete'] is False and metrics['run']['restarts'] == []
