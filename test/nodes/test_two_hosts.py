"""Deployment on two hosts, made of two Linux network namespaces joined by a veth pair.

The plant's host runs plant_node; the operator station runs controller_node, reference_node
and the harness (recorder, gate). DDS traffic between them crosses the veth as UDP, as between
two machines (test/support/netns.py says why it is not shared memory). Discovery: lockstep
with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and ``ROS_STATIC_PEERS`` (unicast only: each
host's address), wall with ``SUBNET`` (multicast over the veth). The link is cut for
``OUTAGE`` seconds in the middle of each run (``ip link set ... down``, then ``up``).

Creating namespaces needs root; without it these tests fail with that reason (CI runs as root)
— they never skip. Marker ``netns`` (``-m 'not netns'`` leaves them out deliberately). What
they measure (how long after link-up data flows again, messages lost or delivered late,
whether the peers stayed in each other's graph, the UDP ports bound) is printed
(``pytest -s``); docs/deployment.md quotes it. ``TANK_CONTROL_TEST_OUTAGE=25`` cuts the link
for longer than the DDS participant lease.
"""
from __future__ import annotations

import json
import os
import re
import secrets
import select
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from support import CONFIG
from support.netns import NetnsUnavailable, TwoHosts, two_hosts

from tank_control.core import params_file
from tank_control.core.trace import Trace
from tank_control.harness.processes import ProcessGroup
from tank_control.harness.scenario_file import load_scenario
from tank_control.harness.runner import simulate

pytestmark = pytest.mark.netns

SUPPORT = Path(__file__).resolve().parents[1] / 'support'
DRIVER, WATCH = SUPPORT / 'netns_harness.py', SUPPORT / 'graph_watch.py'
#: [s] wall time the link stays down (the stimulus, not a wait); TANK_CONTROL_TEST_OUTAGE
#: sets another, e.g. one longer than the DDS participant lease, to measure that case
OUTAGE = float(os.environ.get('TANK_CONTROL_TEST_OUTAGE', '3'))
#: [s] Fast DDS's default participant lease: a peer unheard of for this long is dropped (the
#: plant's publisher leaves the station's graph; printed with an outage longer than this)
LEASE = 20.0
TS_NS = 100_000_000          # plant tick of the scenarios [ns]
NS = 1_000_000_000


@pytest.fixture
def hosts(procs: ProcessGroup) -> Iterator[TwoHosts]:
    """Two namespaces with unique names and addresses; every process is stopped and both
    are removed when the test ends, also when it failed. Without root: the test fails (no
    skip) saying so."""
    manager = two_hosts(f'tc{os.getpid()}{secrets.token_hex(2)}')
    try:
        created = manager.__enter__()
        failure = ''
    except NetnsUnavailable as exc:
        failure = str(exc)
    if failure:
        pytest.fail(f'two-host deployment test not run: {failure}. It creates Linux network '
                    'namespaces and needs root (CI runs it as root).', pytrace=False)
    try:
        yield created
    finally:
        try:
            procs.stop_all()                 # the harness stops its nodes first
        finally:
            manager.__exit__(None, None, None)


class Progress:
    """Lines the driver writes to a FIFO, read as they come (select, no polling)."""

    def __init__(self, path: Path, alive: Callable[[], str | None]) -> None:
        os.mkfifo(path)
        # read-write: the open does not wait for the writer and never sees end-of-file
        self.fd = os.open(path, os.O_RDWR | os.O_NONBLOCK)
        self.alive = alive
        self.buffer = b''
        self.lines: list[str] = []

    def wait(self, condition: Callable[[str], bool], timeout: float) -> str:
        """The first line for which ``condition`` holds; fails on 'failed', a dead driver or
        the deadline."""
        deadline = time.monotonic() + timeout
        while True:
            while b'\n' in self.buffer:
                raw, self.buffer = self.buffer.split(b'\n', 1)
                line = raw.decode()
                self.lines.append(line)
                assert not line.startswith('failed'), line
                if condition(line):
                    return line
            remaining = deadline - time.monotonic()
            assert remaining > 0, f'no such progress line in {timeout:g} s: {self.lines[-3:]}'
            ready, _, _ = select.select([self.fd], [], [], min(remaining, 1.0))
            if ready:
                self.buffer += os.read(self.fd, 65536)
            else:
                dead = self.alive()
                assert dead is None, dead

    def close(self) -> None:
        os.close(self.fd)


def sim_at_least(seconds: float) -> Callable[[str], bool]:
    return lambda line: line.startswith('progress') and float(line.split()[1]) >= seconds


@dataclass(frozen=True)
class Received:
    """One recorded message: when the recorder got it, its stamp, its channel values."""

    log_ns: int
    stamp_ns: int
    values: tuple[float, ...]
    data: bytes


def recorded(mcap: Path) -> dict[str, list[Received]]:
    """Signal topic → messages of ``run.mcap`` in arrival order, with the recorder's times."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    out: dict[str, list[Received]] = {}
    with open(mcap, 'rb') as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        for _, channel, message, msg in reader.iter_decoded_messages(
                topics=['/measurement', '/setpoint', '/manipulated', '/disturbance']):
            stamp = msg.header.stamp.sec * NS + msg.header.stamp.nanosec
            out.setdefault(channel.topic.lstrip('/'), []).append(
                Received(message.log_time, stamp, tuple(msg.position), bytes(message.data)))
    return out


def udp_ports(netns: str) -> dict[str, list[int]]:
    """The UDP ports each process in ``netns`` has bound (``ss``), by program (``plant_node``,
    ``controller_node``, ``reference_node``, ``harness``)."""
    listing = subprocess.run(['ip', 'netns', 'exec', netns, 'ss', '-uapnH'], capture_output=True,
                             text=True, timeout=30).stdout
    out: dict[str, list[int]] = {}
    for line in listing.splitlines():
        fields = line.split()
        match = re.search(r'pid=(\d+)', line)
        if len(fields) < 4 or match is None:
            continue
        try:
            cmdline = Path(f'/proc/{match.group(1)}/cmdline').read_bytes().decode(errors='replace')
        except OSError:
            continue
        program = next((name for name in ('plant_node', 'controller_node', 'reference_node',
                                          'netns_harness') if name in cmdline), None)
        if program is not None:
            out.setdefault(program.replace('netns_', ''), []).append(
                int(fields[3].rsplit(':', 1)[1]))
    return {name: sorted(set(ports)) for name, ports in sorted(out.items())}


def rtps_ports(domain: int, participant: int) -> tuple[int, int]:
    """Discovery and user-data unicast ports of a participant (RTPS 9.6.1.1: PB 7400, DG 250,
    PG 2, d1 10, d3 11)."""
    base = 7400 + 250 * domain
    return base + 10 + 2 * participant, base + 11 + 2 * participant


@dataclass
class CutRun:
    """A harness run with the link cut in the middle: its output folder, when the link went
    down and up [ns, system clock: the clock of the recorder's arrival times and of wall-clock
    stamps], when the graph was up, and the UDP ports bound on each host while it ran."""

    out: Path
    down: int
    up: int
    tick0_after: float
    ports: dict[str, dict[str, list[int]]]
    publishers: list[tuple[int, int]]        # (system time ns, plant publishers the station knows)

    def lease_report(self, end: int) -> str:
        """Whether the station lost the plant's publisher while the link was down (before
        ``end``, the last measurement recorded: the plant stops after it); with an outage well
        inside the lease it must not have."""
        assert any(count == 1 for t, count in self.publishers if t < self.down), self.publishers
        gone = [t for t, count in self.publishers if count == 0 and self.down < t < end]
        back = [t for t, count in self.publishers if count == 1 and gone and t > gone[0]]
        if OUTAGE < LEASE / 2:
            assert not gone, self.publishers
        if not gone:
            return 'the station kept the plant in its graph throughout'
        return (f'the plant left the station\'s graph {(gone[0] - self.down) / 1e9:.1f} s after '
                f'link down' + (f', back {(back[0] - self.up) / 1e9:.2f} s after link up'
                                if back else ', not back'))


def run_with_cut(procs: ProcessGroup, hosts: TwoHosts, scenario: Path, out: Path,
                 env: dict[str, str], cut_at: float) -> CutRun:
    """The harness in the station's namespace with plant_node in the plant's; once simulated
    time reaches ``cut_at`` the link goes down for ``OUTAGE`` s, then up; returns when the run
    is done."""
    def alive() -> str | None:
        proc = procs.processes['harness']
        code = proc.returncode
        return None if code is None else f'harness exited with {code}:\n{proc.tail(30)}'
    fifo = out.parent / f'{out.name}.progress'
    progress = Progress(fifo, alive)
    # -P: the script's folder (test/support, with its mcap.py) must not shadow packages
    argv = hosts.station.exec([sys.executable, '-P', str(DRIVER), str(scenario), str(out),
                               hosts.plant.netns, str(fifo)])
    watch = procs.start('graph_watch', hosts.station.exec(
        [sys.executable, '-P', str(WATCH), '/measurement']), env=env)
    started = time.monotonic()
    procs.start('harness', argv, env=env)
    try:
        progress.wait(sim_at_least(0.0), timeout=120)
        tick0_after = time.monotonic() - started
        progress.wait(sim_at_least(cut_at), timeout=120)
        ports = {host.netns: udp_ports(host.netns) for host in (hosts.plant, hosts.station)}
        hosts.set_link(False)
        down = time.time_ns()                # the link is down once `ip` has returned
        time.sleep(OUTAGE)                   # the outage itself (the stimulus, not a wait)
        up = time.time_ns()                  # it is not up before `ip` runs
        hosts.set_link(True)
        progress.wait(lambda line: line == 'done', timeout=120)
    finally:
        progress.close()
    publishers = [(int(t), int(n)) for t, n in
                  (line.split() for line in watch.log_path.read_text().splitlines()
                   if re.fullmatch(r'\d+ \d+', line))]
    return CutRun(out, down, up, tick0_after, ports, publishers)


def check_ports(run: CutRun, hosts: TwoHosts, domain: int, multicast: bool) -> str:
    """Every node process listens on the unicast ports of the RTPS formula for its participant
    index on its host (and, with multicast discovery, on the domain's multicast port); returns
    what was bound, for the report."""
    base = 7400 + 250 * domain
    plant = run.ports[hosts.plant.netns]
    station = run.ports[hosts.station.netns]
    assert set(rtps_ports(domain, 0)) <= set(plant['plant_node']), plant   # alone on its host
    for index, program in enumerate(sorted(station)):
        assert any(set(rtps_ports(domain, i)) <= set(station[program]) for i in range(4)), station
    for program, ports in (*plant.items(), *station.items()):
        assert (base in ports) == multicast, (program, ports)
    return f'plant host {plant}, station {station}'


def scenario_file(tmp_path: Path, mode: str) -> Path:
    """config/ipdt_pid.yaml shortened (30 s lockstep paced at 4x real time; wall: 4 s, the outage, 3 s), with
    measurement noise, a setpoint ramp and a load step; wall: fail-safe output on stale
    measurements."""
    params = params_file.read(CONFIG / 'ipdt_pid.yaml')
    params['plant'].update({'noise_std': [0.01], 'seed': 7})
    harness = {'stall_timeout': OUTAGE + 30.0}       # the harness waits out the outage
    params['reference'].update({'setpoint.y.times': [0.0, 1.0], 'setpoint.y.values': [0.0, 1.0],
                                'setpoint.y.ramp_rate': 0.5,
                                'disturbance.v.times': [0.0, 7.0],
                                'disturbance.v.values': [0.0, -0.1]})
    if mode == 'lockstep':
        params['controller']['sample_time'] = 0.2     # every second tick: holds in between
        params['harness'] = {**harness, 'duration': 30.0, 'clock_mode': 'lockstep',
                             'real_time_factor': 4.0}
    else:
        params['reference']['sample_time'] = 0.1
        # trigger timer: the sample arithmetic below (the samples between the last measurement
        # and the fail-safe one, stamped with the wall time) is the timer's; with trigger
        # measurement no sample comes between them (docs/nodes.md)
        params['controller'].update({'fail_safe': 'output', 'fail_safe_output': FAIL_SAFE,
                                     'stale_samples': STALE_SAMPLES, 'trigger': 'timer'})
        # the run's simulated time goes on while the link is down: 4 s, the outage, 3 s
        params['harness'] = {**harness, 'duration': 7.0 + OUTAGE, 'clock_mode': 'wall'}
    return params_file.write(params, tmp_path / f'{mode}.yaml')


FAIL_SAFE = 0.375            # fail_safe_output of the wall run (no PID output equals it)
STALE_SAMPLES = 3


def test_lockstep_across_two_hosts_equals_in_process_and_a_link_cut_loses_nothing(
        hosts, procs, ros_env, tmp_path):
    """Lockstep, static peers: every tick of the run equals the in-process loop to 1e-9 on every
    signal, although the link was down for ``OUTAGE`` s in the middle; the loop paused (no tick
    advanced while the link was down beyond the one in flight) and resumed."""
    scenario = scenario_file(tmp_path, 'lockstep')
    env = {**ros_env, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'ROS_STATIC_PEERS': f'{hosts.plant.address};{hosts.station.address}'}
    run = run_with_cut(procs, hosts, scenario, tmp_path / 'lockstep', env, cut_at=8.0)
    out, down, up = run.out, run.down, run.up

    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['mode'] == 'lockstep' and metrics['run']['ticks'] == 301
    assert metrics['run']['missed_samples'] == 0 and metrics['run']['late_samples'] == 0

    # Every tick of every signal equals the in-process loop of the same file.
    ros = Trace.read_csv(out / 'trace.csv')
    expected, _ = simulate(load_scenario(scenario))
    assert list(ros.names) == list(expected.names)
    worst = ros.max_abs_difference(expected)
    assert max(worst.values()) <= 1e-9, worst
    np.testing.assert_array_equal(np.round(ros.t * 10), np.arange(301))

    # Nothing duplicated differently: a re-sent tick was answered with the same bytes.
    messages = recorded(out / 'run.mcap')
    for topic, received in messages.items():
        first: dict[int, bytes] = {}
        for m in received:
            assert first.setdefault(m.stamp_ns, m.data) == m.data, (topic, m.stamp_ns)

    # The cut was real: while the link was down the loop stood still (at most the tick in
    # flight when it went down was completed), and it went on after the link came back.
    measured = messages['measurement']
    before_down = max(m.stamp_ns for m in measured if m.log_ns < down)
    before_up = max(m.stamp_ns for m in measured if m.log_ns < up)
    assert before_up - before_down <= TS_NS, (before_down, before_up)
    assert before_up < 30 * NS
    resumed = min(m.log_ns for m in measured if m.stamp_ns > before_up)
    ports = check_ports(run, hosts, int(ros_env['ROS_DOMAIN_ID']), multicast=False)
    copies = sum(1 for m in measured if m.stamp_ns == before_up + TS_NS)
    print(f'\n[two hosts, lockstep, static peers] tick 0 {run.tick0_after:.1f} s after the '
          f'start; {run.lease_report(measured[-1].log_ns)}; link down at tick '
          f'{before_down // TS_NS} for {(up - down) / 1e9:.2f} s (last tick recorded before '
          f'link up: {before_up // TS_NS}); next tick recorded '
          f'{(resumed - up) / 1e9:.2f} s after link up, in {copies} copies (re-sent while the '
          f'link was down); worst |ros - in-process| '
          f'{max(worst.values()):.3g}; UDP ports (ROS_DOMAIN_ID {ros_env["ROS_DOMAIN_ID"]}): '
          f'{ports}')


def test_wall_clock_across_two_hosts_fails_safe_within_stale_samples_and_resumes(
        hosts, procs, ros_env, tmp_path):
    """Wall clock, multicast discovery (SUBNET): with the link down the controller receives no
    measurement and sends ``fail_safe_output`` from its ``stale_samples``-th sample without one
    until measurements return; then it controls again (recovered bumplessly, as its log says)."""
    scenario = scenario_file(tmp_path, 'wall')
    env = {**ros_env, 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}
    run = run_with_cut(procs, hosts, scenario, tmp_path / 'wall', env, cut_at=4.0)
    out, down, up = run.out, run.down, run.up

    messages = recorded(out / 'run.mcap')
    measured, sent = messages['measurement'], sorted(messages['manipulated'],
                                                     key=lambda m: m.stamp_ns)
    # Nothing the plant published after the link went down reached the station before it was up.
    assert not [m for m in measured if m.stamp_ns > down + TS_NS and m.log_ns < up]
    last = max((m for m in measured if m.log_ns < up), key=lambda m: m.stamp_ns)
    after = [m for m in sent if m.stamp_ns > last.stamp_ns]
    safe = [i for i, m in enumerate(after) if m.values == (FAIL_SAFE,)]
    assert safe, 'the controller never sent its fail-safe output'
    # Samples after the last measurement before the fail-safe one: the one that used it, then
    # stale_samples - 1 without one (the stale_samples-th without one is the fail-safe); one
    # more if it was stamped while that measurement was on its way, one less if the cut took
    # the measurement's datagram to the controller but not the one to the recorder.
    assert STALE_SAMPLES - 1 <= safe[0] <= STALE_SAMPLES + 1, [m.values for m in after[:8]]
    # One episode: fail-safe from then on while the link was down, control after it.
    episode = after[safe[0]:safe[-1] + 1]
    assert all(m.values == (FAIL_SAFE,) for m in episode)
    assert all(m.values == (FAIL_SAFE,) for m in after[safe[0]:] if m.stamp_ns < up)
    resumed = after[safe[-1] + 1:]
    assert len(resumed) >= 10 and FAIL_SAFE not in {v for m in resumed for v in m.values}
    log = (out / 'logs' / 'controller.log').read_text()
    assert 'measurement stale: fail_safe_output' in log
    assert 'measurement recovered after stale episode; control resumed bumplessly' in log

    ports = check_ports(run, hosts, int(ros_env['ROS_DOMAIN_ID']), multicast=True)
    first_back = min(m.log_ns for m in measured if m.log_ns >= up)
    origin = measured[0].stamp_ns                       # a tick: stamps are origin + k ts
    published = set(range(-(-(down - origin) // TS_NS), (up - origin) // TS_NS + 1))
    got = {round((m.stamp_ns - origin) / TS_NS): m for m in measured}
    late = [k for k in published if k in got and got[k].log_ns >= up]
    lost = [k for k in published if k not in got]
    late_inputs = len(recorded_topic(out / 'run.mcap', '/plant/late_inputs'))
    print(f'\n[two hosts, wall, SUBNET] tick 0 {run.tick0_after:.1f} s after the start; '
          f'{run.lease_report(measured[-1].log_ns)}; link down {(up - down) / 1e9:.2f} s; '
          f'fail-safe at sample {safe[0] + 1} after the last measurement; first measurement '
          f'{(first_back - up) / 1e9:.2f} s after link up, control again '
          f'{(resumed[0].stamp_ns - up) / 1e9:.2f} s after link up; measurements published '
          f'while down: {len(published)}, delivered after link up {len(late)}, lost '
          f'{len(lost)}; /plant/late_inputs reports {late_inputs}; UDP ports (ROS_DOMAIN_ID '
          f'{ros_env["ROS_DOMAIN_ID"]}): {ports}')


def recorded_topic(mcap: Path, topic: str) -> list[int]:
    """Arrival times [ns] of the messages of ``topic`` in ``run.mcap``."""
    from mcap.reader import make_reader
    with open(mcap, 'rb') as handle:
        return [message.log_time for _, _, message in make_reader(handle).iter_messages(
            topics=[topic])]
