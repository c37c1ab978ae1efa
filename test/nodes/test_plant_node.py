"""plant_node over real DDS: sample rate and stamps, live dead_time, garbage inputs, diagnostics."""
from __future__ import annotations

import json
import signal
import time

import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.nodes.messages import (ORIGIN_QOS, SIGNAL_QOS, from_joint_state, stamp_to_ns,
                                         to_joint_state)

#: The probe keeps every sample: a plant on its timer does not wait for a slow test process.
RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)


def start_plant(procs, ros_env, node_cmd, tmp_path, **params):
    path = tmp_path / 'plant.yaml'
    path.write_text(json.dumps({'plant': {'ros__parameters': params}}))   # JSON: strings quoted
    return procs.start('plant', node_cmd('plant_node', '--params-file', str(path)), env=ros_env)


class Recorder:
    """Signals (and /diagnostics) seen by the probe."""

    def __init__(self, probe) -> None:
        self.probe = probe
        self.measurements: list[tuple[int, tuple, tuple]] = []
        self.clock: list[int] = []
        self.arrived: dict[str, list[int]] = {'measurement': [], 'clock': []}   # system time [ns]
        self.diagnostics: list[dict[str, str]] = []
        node = probe.node
        self.meas_sub = node.create_subscription(JointState, 'measurement', self._on_measurement,
                                                 RECORD_QOS)
        self.clock_sub = node.create_subscription(Clock, '/clock', self._on_clock, RECORD_QOS)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)
        self.manipulated = node.create_publisher(JointState, 'manipulated', SIGNAL_QOS)
        self.disturbance = node.create_publisher(JointState, 'disturbance', SIGNAL_QOS)

    def _on_measurement(self, msg: JointState) -> None:
        self.arrived['measurement'].append(time.time_ns())
        self.measurements.append(from_joint_state(msg))

    def _on_clock(self, msg: Clock) -> None:
        self.arrived['clock'].append(time.time_ns())
        self.clock.append(stamp_to_ns(msg.clock))

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == 'plant':
                self.diagnostics.append({'level': status.level, 'message': status.message,
                                         **{kv.key: kv.value for kv in status.values}})

    def set_param(self, name, value):
        client = self.probe.node.create_client(SetParameters, '/plant/set_parameters')
        assert self.probe.wait_for(client.service_is_ready, 20)
        future = client.call_async(SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()]))
        assert self.probe.wait_for(future.done, 10)
        return future.result().results[0]

    def y_at(self, t_ns: int) -> float:
        return {s: v for s, _, v in self.measurements}[t_ns][0]


def test_wall_mode_measures_on_the_sample_time_grid_with_exact_stamps(procs, ros_env, node_cmd, probe,
                                                                 tmp_path):
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       output_offset=2.5)
    rec = Recorder(probe)
    assert probe.wait_for(lambda: len(rec.measurements) >= 23, 30), proc.tail()
    stamps = [s for s, _, _ in rec.measurements]
    # At most one message per sample, stamps a whole number of sample_time apart (a period
    # the timer reached over a period late, on a loaded machine, is skipped and counted) ...
    assert all(b > a and (b - a) % 50_000_000 == 0 for a, b in zip(stamps, stamps[1:]))
    # ... on the wall clock, never ahead of it: sample k is published once its instant
    # has come (a plant sampling faster than sample_time would stamp into the future).
    assert all(s <= t for s, t in zip(stamps, rec.arrived['measurement']))
    assert all(names == ('y',) and values == (2.5,) for _, names, values in rec.measurements)
    assert rec.clock == []   # no /clock in wall mode
    # The time base: tick k is stamped origin + k·ts, origin (tick 0) latched on time_origin.
    origins: list[int] = []
    probe.node.create_subscription(Time, 'time_origin', lambda m: origins.append(stamp_to_ns(m)),
                                   ORIGIN_QOS)
    assert probe.wait_for(lambda: origins, 20)
    assert all((s - origins[0]) % 50_000_000 == 0 and s >= origins[0] for s in stamps)
    # A running wall clock cannot be paused (only its first tick can be held).
    result = rec.set_param('lockstep.paused', True)
    assert not result.successful and 'wall' in result.reason


def test_wall_mode_announces_its_time_origin_before_tick_0(procs, ros_env, node_cmd, probe,
                                                           tmp_path):
    """wall: un-paused, the plant publishes the time origin ORIGIN_NOTICE_S (whole periods)
    before tick 0 and measurement 0, stamped with it, once the origin has come: the reference's
    instant 0 reaches the controller before measurement 0 (announced at tick 0, the origin
    raced the measurement and the controller skipped tick 0, or the reference never published
    instant 0)."""
    from tank_control.nodes.plant_node import ORIGIN_NOTICE_S
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.03,
                       gain=1.0, clock_mode='wall', **{'lockstep.paused': True})
    rec = Recorder(probe)
    origins: list[tuple[int, int]] = []        # (origin, system time of its arrival) [ns]
    probe.node.create_subscription(
        Time, 'time_origin', lambda m: origins.append((stamp_to_ns(m), time.time_ns())),
        ORIGIN_QOS)
    assert probe.wait_for(lambda: rec.meas_sub.get_publisher_count(), 30), proc.tail()
    unpaused_at = time.time_ns()
    assert rec.set_param('lockstep.paused', False).successful
    assert probe.wait_for(lambda: rec.measurements, 30), proc.tail()
    notice = -(-round(ORIGIN_NOTICE_S * 1e9) // 30_000_000) * 30_000_000    # whole periods
    [(origin, heard)] = origins
    assert unpaused_at + notice <= origin            # announced ahead, by the notice at least
    assert heard < origin                            # ... and here before its instant
    assert rec.measurements[0][0] == origin          # tick 0 stamped with it
    assert rec.arrived['measurement'][0] >= origin   # published once its instant came


def test_tick_0_waits_for_the_middleware_to_match_what_the_graph_shows(
        procs, ros_env, node_cmd, probe, tmp_path):
    """sim/wall: a reader the graph shows is not yet matched while the endpoint discovery lags
    (seconds on a loaded machine: CI saw the reference hear the time origin 2.8 s late, and
    the run lose its first 28 setpoints); tick 0 waits for the match. A reader that never
    matches (here: incompatible QoS, a transient-local reader of the volatile measurement)
    delays tick 0 by MATCH_WAIT_S, then the plant starts with a warning naming the topic."""
    from rclpy.qos import DurabilityPolicy

    from tank_control.nodes.messages import MATCH_WAIT_S
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       gain=1.0, clock_mode='wall', **{'lockstep.paused': True})
    rec = Recorder(probe)
    incompatible = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.TRANSIENT_LOCAL)
    probe.node.create_subscription(JointState, 'measurement', lambda m: None, incompatible)
    assert probe.wait_for(lambda: rec.meas_sub.get_publisher_count(), 30), proc.tail()
    unpaused_at = time.time_ns()
    assert rec.set_param('lockstep.paused', False).successful
    assert probe.wait_for(lambda: rec.measurements, 30), proc.tail()
    assert rec.arrived['measurement'][0] - unpaused_at >= MATCH_WAIT_S * 1e9
    assert probe.wait_for(lambda: 'measurement not matched' in proc.tail(50), 10), proc.tail()


def test_before_tick_0_diagnostics_report_the_matched_endpoints(procs, ros_env, node_cmd, probe,
                                                                tmp_path):
    """Paused before tick 0, the plant reports on /diagnostics how many readers the middleware
    has matched to each of its writers and writers to each input (``matched_readers.<topic>``,
    ``matched_writers.<topic>``), soon after a change: the harness starts the clock once they
    reach what its own graph shows."""
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       gain=1.0, clock_mode='wall', **{'lockstep.paused': True})
    rec = Recorder(probe)        # one reader of measurement, writers of manipulated, disturbance
    probe.node.create_subscription(Time, 'time_origin', lambda m: None, ORIGIN_QOS)

    def reported(key: str) -> int | None:
        values = [d.get(key) for d in rec.diagnostics[-1:]]
        return int(values[0]) if values and values[0] is not None else None
    assert probe.wait_for(lambda: reported('matched_readers./measurement') == 1
                          and reported('matched_readers./time_origin') == 1
                          and reported('matched_writers./manipulated') == 1
                          and reported('matched_writers./disturbance') == 1, 30), \
        (rec.diagnostics[-1:], proc.tail())
    assert reported('matched_readers./applied_input') == 0    # nobody reads it here
    assert not rec.measurements                               # still before tick 0


def test_wall_mode_a_disturbance_sent_ahead_of_its_instant_acts_from_it(procs, ros_env, node_cmd,
                                                                        probe, tmp_path):
    """wall: the reference publishes each instant ``wall.lead`` ahead of it; the plant holds a
    disturbance stamped t_e until the step that starts at t_e. IPDT without dead time, k1 = 1:
    y stays 0 through t_e and is k1·v·(t − t_e) after it (whatever periods a loaded timer
    skipped). 1 s ahead is beyond the default ``max_future_stamp`` (5 ticks): raised to 2 s."""
    ts = 50_000_000
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       gain=1.0, dead_time=0.0, max_future_stamp=2.0)
    rec = Recorder(probe)
    assert probe.wait_for(lambda: rec.measurements and rec.disturbance.get_subscription_count(),
                          30), proc.tail()
    t_e = rec.measurements[-1][0] + 20 * ts          # 1 s ahead of the latest measurement
    rec.disturbance.publish(to_joint_state(t_e, ['v'], [1.0]))
    assert probe.wait_for(lambda: rec.measurements[-1][0] >= t_e + 2 * ts, 30), proc.tail()
    y = {stamp: values[0] for stamp, _, values in rec.measurements}
    assert all(value == 0.0 for stamp, value in y.items() if stamp <= t_e)
    after = sorted(stamp for stamp in y if stamp > t_e)
    assert after, y
    for stamp in after:
        assert y[stamp] == pytest.approx((stamp - t_e) / 1e9, abs=1e-12), (stamp - t_e, y[stamp])


def test_wall_mode_stamps_each_measurement_with_its_instant_and_counts_skipped_periods(
        procs, ros_env, node_cmd, probe, tmp_path):
    """A plant process frozen (SIGSTOP) for at least 0.3 s at 20 ms ticks: on waking it
    publishes the measurement of the instant that has come, stamped with it (on the grid
    origin + k·ts, never ahead of its arrival), not the ticks it slept through; those are
    integrated and counted in /diagnostics ``missed_samples``: every tick is published or
    counted, exactly once."""
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.02,
                       diagnostics_period=0.1)
    rec = Recorder(probe)
    ts = 20_000_000
    assert probe.wait_for(lambda: len(rec.measurements) >= 10, 30), proc.tail()
    first = rec.measurements[0][0]
    # a report after the probe's first measurement: the count from here on is compared
    assert probe.wait_for(lambda: any(int(d['time_origin_ns']) + round(float(d['sim_time']) * 1e9)
                                      > first for d in rec.diagnostics), 30), proc.tail()
    before = len(rec.diagnostics) - 1
    proc.popen.send_signal(signal.SIGSTOP)          # the plant process misses >= 15 periods
    probe.wait_for(lambda: False, 0.3)
    proc.popen.send_signal(signal.SIGCONT)
    seen = len(rec.measurements)
    assert probe.wait_for(lambda: len(rec.measurements) >= seen + 10, 30), proc.tail()
    after = len(rec.diagnostics)
    assert probe.wait_for(lambda: len(rec.diagnostics) > after, 10), proc.tail()
    stamps = [s for s, _, _ in rec.measurements]
    origin = int(rec.diagnostics[0]['time_origin_ns'])
    # every stamp on the plant's grid, in order, none ahead of its arrival
    assert all((s - origin) % ts == 0 for s in stamps)
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert all(s <= t for s, t in zip(stamps, rec.arrived['measurement']))
    # the freeze is one gap of at least 0.3 s / 20 ms - 1 ticks
    gaps = [(b - a) // ts - 1 for a, b in zip(stamps, stamps[1:])]
    assert max(gaps) >= 14, gaps
    # every tick without a measurement is counted once, between two reports
    d1, d2 = rec.diagnostics[before], rec.diagnostics[-1]

    def tick(d):
        return round(float(d['sim_time']) * 1e9) // ts
    k1, k2 = tick(d1), tick(d2)
    published = {(s - origin) // ts for s in stamps}
    assert k2 in published and k1 in published
    assert int(d2['missed_samples']) - int(d1['missed_samples']) == sum(
        1 for k in range(k1 + 1, k2 + 1) if k not in published)
    assert int(d2['missed_samples']) + int(d2['ticks']) == k2 + 1


def test_wall_mode_says_when_the_plant_cannot_keep_real_time(procs, ros_env, node_cmd, probe,
                                                             tmp_path):
    """An integration step far below the tick (5·10^4 RK4 steps per 50 ms tick, the smallest
    step allowed: ≈ 150 ms of CPU on this machine; 10^4 steps took 37 ms once the tank's RK4
    was made faster, and kept up) makes each tick cost more than its period: /diagnostics is
    WARN, saying how far behind and what a tick costs, instead of ok."""
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='mixing_tank',
                       sample_time=0.05, integration_step=1e-6, diagnostics_period=0.5)
    rec = Recorder(probe)

    def behind():
        return any('behind real time' in d['message'] for d in rec.diagnostics)
    assert probe.wait_for(behind, 60), (rec.diagnostics[-1:], proc.tail())
    report = next(d for d in rec.diagnostics if 'behind real time' in d['message'])
    assert report['level'] == DiagnosticStatus.WARN
    assert float(report['step_time_ms']) > 50.0               # a tick costs more than 50 ms
    assert 'instead of 1x' in report['message']


def test_lockstep_ticks_carry_k_times_ts_and_a_live_dead_time_change_acts(procs, ros_env,
                                                                          node_cmd, probe,
                                                                          tmp_path):
    # IPDT k1 = 1, L = 0.3 s, ts = 0.1 s; the probe is the controller (u) of every tick.
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.1,
                       gain=1.0, dead_time=0.3, clock_mode='lockstep', real_time_factor=0.0,
                       **{'lockstep.wait_for_reference': False, 'lockstep.resend_period': 0.2})
    rec = Recorder(probe)
    u_of_tick: dict[int, float] = {}

    def answer(k: int) -> None:
        """Answer ticks in order up to k with u from u_of_tick (0 by default)."""
        while True:
            if not probe.wait_for(lambda: rec.measurements, 20):
                raise AssertionError(proc.tail())
            stamp = rec.measurements[-1][0]
            j = stamp // 100_000_000
            rec.manipulated.publish(to_joint_state(stamp, ['u'], [u_of_tick.get(j, 0.0)]))
            if j >= k:
                return
            probe.wait_for(lambda: rec.measurements[-1][0] > stamp, 1.0)

    answer(2)
    # Ticks 0, 1, 2 in order; a tick may come more than once (re-sent while its answer was
    # on the way, e.g. on a loaded machine), so the distinct stamps are compared.
    stamps = [s for s, _, _ in rec.measurements]
    assert stamps == sorted(stamps)
    assert sorted(set(stamps)) == [0, 100_000_000, 200_000_000]
    assert probe.wait_for(lambda: rec.clock and rec.clock[-1] >= 200_000_000, 30)
    assert 200_000_000 in rec.clock and rec.clock == sorted(rec.clock)
    # Out of range for the model (above max_dead_time): rejected with the reason.
    result = rec.set_param('dead_time', 1e3)
    assert not result.successful and 'dead_time' in result.reason and 'max_dead_time' in result.reason
    # Settings that only act at start-up are read-only: a live change is refused, not ignored.
    for name, value in (('diagnostics_period', 2.0), ('lockstep.wait_for_reference', True)):
        result = rec.set_param(name, value)
        assert not result.successful and 'read-only' in result.reason, (name, result.reason)
    result = rec.set_param('dead_tme', 0.6)
    assert not result.successful and result.reason == 'dead_tme: unknown parameter; did you ' \
                                                       'mean dead_time?'
    assert rec.set_param('dead_time', 0.6).successful
    # Step u = 1 from tick 3: with the new dead time y rises from t = 0.3 + 0.6 s on.
    u_of_tick.update({k: 1.0 for k in range(3, 40)})
    answer(15)
    for k in range(3, 15):
        expected = max(0.0, (k - 3) * 0.1 - 0.6)   # k1·(t − t_step − L), closed form
        assert rec.y_at(k * 100_000_000) == pytest.approx(expected, abs=1e-12), k
    # In order; a tick seen more than once was re-sent (unanswered for resend_period, e.g.
    # before discovery matched the probe's answers) and is the identical message.
    stamps = [s for s, _, _ in rec.measurements]
    assert stamps == sorted(stamps)
    assert all(a == b for a, b in zip(rec.measurements, rec.measurements[1:]) if a[0] == b[0])


def test_garbage_inputs_are_ignored_counted_and_the_last_valid_value_kept(procs, ros_env,
                                                                          node_cmd, probe,
                                                                          tmp_path):
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       gain=1.0, dead_time=0.0, diagnostics_period=0.1)
    rec = Recorder(probe)
    assert probe.wait_for(lambda: rec.measurements and rec.manipulated.get_subscription_count(),
                          20), proc.tail()
    rec.manipulated.publish(to_joint_state(0, ['u'], [2.0]))
    bad = [to_joint_state(0, ['u'], [float('nan')]),      # non-finite
           to_joint_state(0, ['w'], [1.0]),                # unknown channel
           to_joint_state(0, ['u', 'x'], [1.0])]           # names/positions differ
    for msg in bad:
        rec.manipulated.publish(msg)
    rec.disturbance.publish(to_joint_state(0, ['v'], [float('inf')]))

    def counted():
        return rec.diagnostics and rec.diagnostics[-1].get('ignored.manipulated') == '3' \
            and rec.diagnostics[-1].get('ignored.disturbance') == '1'
    assert probe.wait_for(counted, 30), (rec.diagnostics[-1:], proc.tail())
    assert rec.diagnostics[-1]['ignored_inputs'] == '4'
    # The plant still integrates the last valid u = 2 (slope k1·u = 2 per second).
    n = len(rec.measurements)
    assert probe.wait_for(lambda: len(rec.measurements) > n + 2, 30)
    (_, _, (y0,)), (_, _, (y1,)) = rec.measurements[-2:]
    assert y1 - y0 == pytest.approx(2.0 * 0.05, abs=1e-12)
    log = proc.tail(50)
    assert log.count('non-finite value') == 2 and log.count("unknown channel(s) 'w'") == 1
    assert proc.returncode is None   # still running


def test_sim_mode_publishes_clock_at_the_real_time_factor(procs, ros_env, node_cmd, probe,
                                                         tmp_path):
    rec = Recorder(probe)
    started = time.time_ns()
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='fopdt', sample_time=0.1,
                       clock_mode='sim', real_time_factor=5.0)
    assert probe.wait_for(lambda: len(rec.clock) >= 28, 30), proc.tail()
    assert all(b - a == 100_000_000 for a, b in zip(rec.clock, rec.clock[1:]))
    # Simulated time never runs ahead of 5 x the wall time since the plant was started
    # (tick k is due k·ts/5 after its start); behind it only on a loaded machine.
    assert all(t_k / 5.0 <= arrived - started
               for t_k, arrived in zip(rec.clock, rec.arrived['clock']))
    stamps = [s for s, _, _ in rec.measurements]
    assert stamps and all(s % 100_000_000 == 0 for s in stamps)   # on the k·ts grid


def test_tank_reports_clipped_negative_flows_on_diagnostics(procs, ros_env, node_cmd, probe,
                                                             tmp_path):
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='mixing_tank', sample_time=0.05,
                       diagnostics_period=0.1)
    rec = Recorder(probe)
    assert probe.wait_for(lambda: rec.measurements and rec.manipulated.get_subscription_count(),
                          20), proc.tail()
    assert rec.measurements[-1][1] == ('h', 'T_out')
    rec.manipulated.publish(to_joint_state(0, ['F_H', 'F_Cin'], [-5.0, 37.0]))   # finite, < 0

    def clipped():
        return rec.diagnostics and int(rec.diagnostics[-1].get('model.clipped_flows', 0)) > 0
    assert probe.wait_for(clipped, 30), rec.diagnostics[-1:]
    last = rec.diagnostics[-1]
    assert last['level'] == b'\x01' and 'clipped flows' in last['message']   # WARN
    assert last['ignored_inputs'] == '0'           # a negative flow is physics, not garbage


def test_sim_mode_clock_stands_still_while_paused(procs, ros_env, node_cmd, probe, tmp_path):
    """lockstep.paused holds the sim clock too: nothing before it is released (a recorder
    can join first and see tick 0), and simulated time does not move while paused again."""
    ts_ns = 100_000_000
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='fopdt', sample_time=0.1,
                       clock_mode='sim', real_time_factor=10.0, diagnostics_period=0.05,
                       **{'lockstep.paused': True})
    rec = Recorder(probe)
    assert probe.wait_for(lambda: rec.meas_sub.get_publisher_count()
                          and rec.clock_sub.get_publisher_count() and len(rec.diagnostics) >= 3,
                          30), proc.tail()
    assert all(d['ticks'] == '0' and d['paused'] == 'True' for d in rec.diagnostics)
    assert rec.clock == [] and rec.measurements == []

    assert rec.set_param('lockstep.paused', False).successful
    assert probe.wait_for(lambda: len(rec.clock) >= 5, 30), proc.tail()
    assert rec.set_param('lockstep.paused', True).successful
    # The plant's report after the pause: ticks published so far; all of them arrive.
    n = len(rec.diagnostics)
    assert probe.wait_for(lambda: len(rec.diagnostics) >= n + 2, 30)
    ticks = int(rec.diagnostics[-1]['ticks'])
    assert rec.diagnostics[-1]['paused'] == 'True'
    assert probe.wait_for(lambda: len(rec.clock) >= ticks, 30)
    # ... and no more: three further reports later the count and the clock are unchanged.
    n = len(rec.diagnostics)
    assert probe.wait_for(lambda: len(rec.diagnostics) >= n + 3, 30)
    assert int(rec.diagnostics[-1]['ticks']) == ticks
    assert rec.clock == [k * ts_ns for k in range(ticks)]      # from tick 0, none missed

    # Released again, the clock goes on from the next tick: no jump over the pause.
    assert rec.set_param('lockstep.paused', False).successful
    assert probe.wait_for(lambda: len(rec.clock) >= ticks + 5, 30), proc.tail()
    assert rec.clock == [k * ts_ns for k in range(len(rec.clock))]
    assert [s for s, _, _ in rec.measurements] == [k * ts_ns for k in range(len(rec.measurements))]


@pytest.mark.parametrize('mode', ['wall', 'sim'])
def test_a_plant_without_controller_and_reference_says_what_it_waits_for(
        procs, ros_env, node_cmd, probe, tmp_path, mode):
    """Started by hand without its partners, a wall or sim plant reports WARN on /diagnostics
    and in its log naming what it waits for (not ``ok``), and clears when they come."""
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.1,
                       clock_mode=mode, real_time_factor=1.0)
    rec = Recorder(probe)
    words = ('waiting for manipulated (controller), disturbance (reference): nothing received '
             'in ')

    def warned():
        return [d for d in rec.diagnostics
                if d['level'] == DiagnosticStatus.WARN and words in d['message']]
    assert probe.wait_for(warned, 30), (rec.diagnostics[-3:], proc.tail())
    assert warned()[0]['message'].endswith('s; inputs held at their initial values')
    assert probe.wait_for(lambda: words in proc.log_path.read_text(), 10), proc.tail()
    assert '[WARN]' in [line for line in proc.log_path.read_text().splitlines()
                        if words in line][0]
    # the controller comes: only the reference is awaited; then both: ok, and logged
    seen = len(rec.diagnostics)
    assert probe.wait_for(lambda: rec.measurements, 10)

    def send(publisher, name, value):
        stamp = rec.measurements[-1][0]
        publisher.publish(to_joint_state(stamp, [name], [value]))

    def only_reference():
        send(rec.manipulated, 'u', 0.0)
        return any(d['message'].startswith('waiting for disturbance (reference): nothing')
                   for d in rec.diagnostics[seen:])
    assert probe.wait_for(only_reference, 30), rec.diagnostics[-3:]

    def moving():       # (a loaded host may still warn that the plant is behind real time)
        send(rec.manipulated, 'u', 0.0)
        send(rec.disturbance, 'v', 0.0)
        return len(rec.diagnostics) > seen and 'waiting' not in rec.diagnostics[-1]['message'] \
            and 'held' not in rec.diagnostics[-1]['message']
    assert probe.wait_for(moving, 30), rec.diagnostics[-3:]
    assert probe.wait_for(lambda: 'inputs arrive: the loop moves' in proc.log_path.read_text(),
                          10), proc.tail()


def test_wall_mode_an_input_stamped_in_the_future_is_refused_and_the_inputs_go_on(
        procs, ros_env, node_cmd, probe, tmp_path):
    """One ``manipulated`` stamped 10 s after the latest measurement (and one an hour, one at
    the largest stamp, 2038) and a ``disturbance`` an hour ahead are refused (``rejected_future``, /diagnostics
    WARN); the next valid ``u`` is integrated. (Before: the 10 s one was taken and every valid
    input after it was "older than the one held" for 10 s.) IPDT, k1 = 1, no dead time: the
    slope of y is u."""
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       gain=1.0, dead_time=0.0, diagnostics_period=0.1)
    rec = Recorder(probe)
    assert probe.wait_for(lambda: rec.measurements and rec.manipulated.get_subscription_count()
                          and rec.disturbance.get_subscription_count(), 30), proc.tail()
    latest = rec.measurements[-1][0]
    rec.manipulated.publish(to_joint_state(latest, ['u'], [2.0]))
    for ahead_s in (10.0, 3600.0, (2**31 - 1) - latest / 1e9):    # ... the largest stamp
        rec.manipulated.publish(to_joint_state(latest + int(ahead_s * 1e9), ['u'], [0.0]))
    rec.disturbance.publish(to_joint_state(latest + 3600 * 10**9, ['v'], [-5.0]))

    def slope():
        (s0, _, (y0,)), (s1, _, (y1,)) = rec.measurements[-2:]
        return (y1 - y0) / ((s1 - s0) / 1e9)

    def integrates(u):
        def check():
            rec.manipulated.publish(to_joint_state(rec.measurements[-1][0], ['u'], [u]))
            n = len(rec.measurements)
            probe.wait_for(lambda: len(rec.measurements) >= n + 2, 5)
            return slope() == pytest.approx(u, abs=1e-9)
        return check
    assert probe.wait_for(integrates(2.0), 30), (rec.measurements[-3:], proc.tail())
    assert probe.wait_for(integrates(-1.0), 30), (rec.measurements[-3:], proc.tail())
    assert probe.wait_for(lambda: rec.diagnostics and
                          rec.diagnostics[-1].get('rejected_future') == '4', 30), \
        (rec.diagnostics[-1:], proc.tail())
    assert rec.diagnostics[-1]['level'] == DiagnosticStatus.WARN
    assert 'future' in rec.diagnostics[-1]['message']


def test_wall_mode_a_stream_taken_as_a_clock_step_gives_way_to_inputs_on_the_plant_s_clock(
        procs, ros_env, node_cmd, probe, tmp_path):
    """A writer sends ``manipulated`` stamped an hour ahead, u = 50, long enough to be taken as
    a clock step (core/stamps.py: every message refused for ``RECOVER_S`` and at least
    ``RECOVER_MESSAGES``); then the controller's own inputs, on the plant's clock, come again.
    They are integrated at once — the stepped value is not held until real time reaches its
    stamp (before: an hour, any process on the domain could pin the input so). IPDT, k1 = 1,
    no dead time: the slope of y is u."""
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       gain=1.0, dead_time=0.0, diagnostics_period=0.1)
    rec = Recorder(probe)
    assert probe.wait_for(lambda: rec.measurements and rec.manipulated.get_subscription_count(),
                          30), proc.tail()

    def slope():
        (s0, _, (y0,)), (s1, _, (y1,)) = rec.measurements[-2:]
        return (y1 - y0) / ((s1 - s0) / 1e9)

    def integrates(u, ahead_ns=0):
        def check():
            rec.manipulated.publish(to_joint_state(rec.measurements[-1][0] + ahead_ns, ['u'],
                                                   [u]))
            n = len(rec.measurements)
            probe.wait_for(lambda: len(rec.measurements) >= n + 2, 5)
            return slope() == pytest.approx(u, abs=1e-9)
        return check
    assert probe.wait_for(integrates(50.0, 3600 * 10**9), 60), (rec.measurements[-3:],
                                                                 proc.tail())
    assert 'clock step' in proc.tail(50)
    assert probe.wait_for(integrates(-1.0), 30), (rec.measurements[-3:], proc.tail())
    assert 'going back' in proc.tail(50)


def test_a_message_with_many_unknown_channel_names_costs_the_plant_no_more_than_a_tick(
        procs, ros_env, node_cmd, probe, tmp_path):
    """A ``manipulated`` with 100 000 unknown channel names is refused whole (more than
    ``MAX_NAMES``: ``oversized_inputs``) before its names are decoded; one with 200 is
    counted (``unknown_channels``) and logged once with the count, not once per name. The
    plant keeps ticking (before: > 44 s of one warning per name)."""
    proc = start_plant(procs, ros_env, node_cmd, tmp_path, plant='ipdt', sample_time=0.05,
                       gain=1.0, dead_time=0.0, diagnostics_period=0.1)
    rec = Recorder(probe)
    assert probe.wait_for(lambda: rec.measurements and rec.manipulated.get_subscription_count(),
                          30), proc.tail()
    many = [f'x{i}' for i in range(100_000)]
    rec.manipulated.publish(to_joint_state(0, many, [1.0] * len(many)))
    some = [f'y{i}' for i in range(200)]            # at most MAX_NAMES (256)
    rec.manipulated.publish(to_joint_state(0, some, [1.0] * len(some)))

    def counted():
        d = rec.diagnostics[-1] if rec.diagnostics else {}
        return d.get('oversized_inputs') == '1' and d.get('unknown_channels') == str(len(some))
    assert probe.wait_for(counted, 60), (rec.diagnostics[-1:], proc.tail())
    n = len(rec.measurements)
    assert probe.wait_for(lambda: len(rec.measurements) >= n + 10, 30)    # still ticking
    log = proc.tail(200)
    assert 'at most' in log and log.count('unknown channel') == 1, log
