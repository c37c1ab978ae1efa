"""The plant's clock protocol (nodes/protocol/plant.py) without ROS: ticks, answers, re-sends,
late answers. The DDS tests (test_plant_node.py) keep runs per mode end to end."""
from __future__ import annotations

import numpy as np

from tank_control.core.stamps import FutureStamps, future_tolerance_ns
from tank_control.nodes.cdr import signal_from_cdr
from tank_control.nodes.protocol.plant import (LockstepPlant, SimPlant, WallPlant,
                                               plant_clock)

TS = 0.1
TS_NS = 100_000_000


class Integrator:
    """y' = u + v (a pure integrator), exact for held inputs."""

    output_names, input_names, disturbance_names = ('y',), ('u',), ('v',)
    nominal_inputs = {'u': 0.0}

    def __init__(self) -> None:
        self.y = 0.0

    def outputs(self):
        return np.array([self.y])

    def step(self, u, d, dt):
        self.y += (u[0] + d[0]) * dt


class Noise:
    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def sample(self):
        return self.rng.normal(0.0, 0.5, 1)


class Timer:
    def __init__(self, period_s, callback, autostart) -> None:
        self.timer_period_ns = int(period_s * 1e9)
        self.callback, self.running = callback, autostart

    def cancel(self) -> None:
        self.running = False

    def reset(self) -> None:
        self.running = True


class Host:
    def __init__(self, paused=False, rtf=0.0) -> None:
        self.paused, self.real_time_factor = paused, rtf
        self.timers: list[Timer] = []
        self.measurements: list[bytes] = []
        self.clock: list[bytes] = []
        self.applied: list[bytes] = []
        self.origins: list[int] = []
        self.values: list[tuple[int, list]] = []       # each tick's measured values (OPC UA)
        self.late: list[tuple[int, list, list]] = []
        self.warnings: list[str] = []

    def timer(self, period_s, callback, autostart=True):
        self.timers.append(Timer(period_s, callback, autostart))
        return self.timers[-1]

    def destroy(self, timer):
        self.timers.remove(timer)

    def publish_measurement(self, msg):
        self.measurements.append(msg)

    def publish_clock(self, msg):
        self.clock.append(msg)

    def publish_applied(self, msg):
        self.applied.append(msg)

    def publish_origin(self, origin_ns):
        self.origins.append(origin_ns)

    def measured(self, stamp_ns, y):
        self.values.append((stamp_ns, list(y)))

    def publish_late(self, t_ns, names, values):
        self.late.append((t_ns, names, values))

    def ros_now_ns(self):
        return 1_700_000_000_000_000_000

    def match_wait(self):
        return False

    def apply_pending(self):
        pass

    def warning(self, text):
        self.warnings.append(text)


def make(cls, host, **values):
    values = {'sample_time': TS, 'lockstep.resend_period': 0.1, 'real_time_factor': 0.0,
              'lockstep.wait_for_reference': True, 'lockstep.record_window': 0, **values}
    counters = {'ticks': 0, 'resent_ticks': 0, 'late_inputs': 0, 'missed_samples': 0}
    future = FutureStamps(future_tolerance_ns(None, TS, cls.ticks))
    return cls(host, Integrator(), Noise(3), values, counters, future, 'session')


def measured(host):
    return [signal_from_cdr(m)[0] for m in host.measurements]


def test_the_mode_picks_the_protocol_once():
    assert [plant_clock(m) for m in ('lockstep', 'sim', 'wall')] == [LockstepPlant, SimPlant,
                                                                     WallPlant]
    assert LockstepPlant.ticks and not SimPlant.ticks and not WallPlant.publishes_clock


def test_unanswered_lockstep_tick_is_resent_unchanged_with_the_same_noise():
    """Nobody answers: tick 0 again at every re-send period, the very same message (one noise
    draw), /clock first; /diagnostics names what it waits for."""
    host = Host()
    plant = make(LockstepPlant, host)
    plant.start()
    assert host.origins == [0] and len(host.measurements) == 1
    for _ in range(3):
        plant.sent_at -= 1.0                     # a re-send period has passed
        plant.on_resend()
    assert len(set(host.measurements)) == 1 and len(host.measurements) == 4
    assert signal_from_cdr(host.measurements[0])[3] != (0.0,)        # noise drawn
    # the tick's values as numbers, once (what an OPC UA server serves), equal to the message
    assert [(0, list(signal_from_cdr(host.measurements[0])[3]))] == host.values
    assert plant.counters['resent_ticks'] == 3
    assert plant.waiting_for() == 'manipulated, disturbance'
    plant.on_resend()                            # not due yet: nothing
    assert len(host.measurements) == 4


def test_lockstep_a_tick_is_integrated_with_its_answers_once_all_came():
    host = Host()
    plant = make(LockstepPlant, host)
    plant.start()
    plant.input('manipulated', 0, ('u',), {'u': 2.0}, ('u',))
    assert measured(host) == [0]                 # the disturbance of tick 0 is missing
    plant.input('disturbance', 0, ('v',), {'v': 1.0}, ('v',))
    assert measured(host) == [0, TS_NS] and plant.k == 1
    assert plant.plant.y == 3.0 * TS             # integrated with u = 2, v = 1
    # an answer for a tick already integrated is a stale duplicate: nothing happens
    plant.input('manipulated', 0, ('u',), {'u': 9.0}, ('u',))
    assert measured(host) == [0, TS_NS] and plant.u == {'u': 2.0}
    # the disturbance is a zero-order-hold stream: one stamped ahead answers the ticks up to
    # its stamp, and manipulated alone completes them
    plant.input('disturbance', 3 * TS_NS, ('v',), {'v': 1.0}, ('v',))
    assert measured(host) == [0, TS_NS]
    plant.input('manipulated', TS_NS, ('u',), {'u': 0.0}, ('u',))
    plant.input('manipulated', 2 * TS_NS, ('u',), {'u': 0.0}, ('u',))
    assert measured(host) == [0, TS_NS, 2 * TS_NS, 3 * TS_NS]


def test_a_lockstep_stall_names_a_silent_reference_though_the_controller_is_missing():
    """The reference was killed after its last disturbance reached the plant but before its
    setpoint reached the controller: the tick lacks only manipulated, yet the stall names the
    reference too, which has not answered a re-sent /clock; a live one, re-sending, is not."""
    for alive in (False, True):
        host = Host()
        plant = make(LockstepPlant, host)
        plant.start()
        plant.input('disturbance', 6 * TS_NS, ('v',), {'v': 0.0}, ('v',))   # held ahead
        # a second passes unanswered (every instant the plant noted moves 1 s back)
        plant.tick_published_at -= 1.0
        plant.sent_at -= 1.0
        plant.arrivals = {k: (at - 1.0, gap) for k, (at, gap) in plant.arrivals.items()}
        plant.on_resend()
        if alive:                                # the reference answers the re-sent /clock
            plant.input('disturbance', 6 * TS_NS, ('v',), {'v': 0.0}, ('v',))
        report = plant.stall_report()
        assert 'waiting for manipulated (controller)' in report
        assert ('disturbance (reference)' in report) == (not alive), report


def test_lockstep_record_window_holds_a_tick_until_the_recorder_acknowledges():
    host = Host()
    plant = make(LockstepPlant, host, **{'lockstep.record_window': 2,
                                         'lockstep.wait_for_reference': False})
    plant.start()
    plant.input('manipulated', 0, ('u',), {'u': 0.0}, ('u',))
    assert measured(host) == [0]                 # tick 1 waits for tick 0 to be recorded
    plant.recorded(0)
    assert measured(host) == [0, TS_NS]
    for k in (1, 2):
        plant.input('manipulated', k * TS_NS, ('u',), {'u': 0.0}, ('u',))
    assert measured(host) == [0, TS_NS, 2 * TS_NS]   # window 2 past tick 0
    plant.recorded(2 * TS_NS)
    assert measured(host)[-1] == 3 * TS_NS


def test_sim_reports_inputs_that_came_after_their_tick_was_integrated():
    """Tick k answered only once tick k+1 is out — after the plant integrated [t_k, t_k+1)
    with what it held: every answer is reported late, once, with the values the plant used
    (the previous answer; the plant starts at u = 0)."""
    host = Host()
    plant = make(SimPlant, host, real_time_factor=2.0)
    plant.start()
    answered = {}
    for k in range(8):
        plant.on_timer()                         # integrates [t_k, t_k+1), publishes k+1
        answered[k * TS_NS] = k + 1.0
        plant.input('manipulated', k * TS_NS, ('u',), {'u': k + 1.0}, ('u',))
    assert host.late == [(k * TS_NS, ['u'], [float(k)]) for k in range(8)]
    assert plant.counters['late_inputs'] == 8
    assert measured(host) == [k * TS_NS for k in range(9)]
    assert len(host.clock) == 9


def test_sim_clock_stands_still_while_paused_and_resumes_a_period_later():
    host = Host(paused=True)
    plant = make(SimPlant, host, real_time_factor=1.0)
    plant.start()
    assert host.measurements == [] and not host.timers[0].running
    plant.on_timer()                             # a call that was due when the pause came
    assert host.measurements == []
    host.paused = False
    plant.set_paused(False, True, True)
    assert measured(host) == [0] and host.timers[0].running


def test_wall_holds_a_disturbance_sent_ahead_until_its_step():
    host = Host()
    plant = make(WallPlant, host)
    plant.start()
    assert plant.announced and host.origins == [plant.stamp_offset_ns]
    # a running wall clock cannot be paused (only held before its origin is announced)
    assert 'wall clock' in plant.pause_refused(True) and plant.pause_refused(False) is None
    assert make(SimPlant, Host(), real_time_factor=1.0).pause_refused(True) is None
    origin = plant.stamp_offset_ns
    plant.tick_msgs = (b'', None)                # tick 0 published
    plant.input('disturbance', origin + 2 * TS_NS, ('v',), {'v': 1.0}, ('v',))
    plant.step()
    assert plant.d == {'v': 0.0}                 # stamped t_2: not yet
    plant.step()
    plant.step()
    assert plant.d == {'v': 1.0} and plant.plant.y == TS   # acts from t_2 on


def test_sim_and_wall_an_input_older_than_the_values_held_is_refused_and_counted():
    """An unstamped (stamp 0) manipulated or disturbance on a running plant is not taken: the
    values held stay, it is counted (``rejected_past``) and logged once per diagnostics
    period (``past_logged``), not reported as a late answer."""
    for cls in (SimPlant, WallPlant):
        host = Host()
        plant = make(cls, host, real_time_factor=1.0)
        plant.start()
        origin = plant.stamp_offset_ns
        plant.tick_msgs = (b'', None)
        for _ in range(3):
            plant.step()
        plant.input('manipulated', origin + 3 * TS_NS, ('u',), {'u': 2.0}, ('u',))
        plant.input('disturbance', origin + 3 * TS_NS, ('v',), {'v': 0.5}, ('v',))
        late = list(host.late)
        for _ in range(2):
            plant.input('manipulated', 0, ('u',), {'u': 9.0}, ('u',))
            plant.input('disturbance', 0, ('v',), {'v': 9.0}, ('v',))
        plant.step()
        assert plant.u == {'u': 2.0} and plant.d == {'v': 0.5}, cls
        assert plant.counters['rejected_past'] == 4 and host.late == late, cls
        refused = [w for w in host.warnings if 'refused' in w]
        assert len(refused) == 2 and 'unstamped' in refused[0], (cls, host.warnings)
        plant.past_logged.clear()                  # the next diagnostics period
        plant.input('manipulated', 0, ('u',), {'u': 9.0}, ('u',))
        assert len([w for w in host.warnings if 'refused' in w]) == 3
