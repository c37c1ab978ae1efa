"""The controller's clock protocol (nodes/protocol/controller.py) without ROS: when it samples,
with what, stamped how. The DDS tests (test_controller_node.py) keep runs per mode end to end."""
from __future__ import annotations

import numpy as np

from tank_control.core.stamps import FutureStamps, future_tolerance_ns
from tank_control.nodes.protocol.controller import (LockstepClock, SimClock, WallArrivalClock,
                                                    WallTimerClock, controller_clock,
                                                    resolved_mode)

TS_NS = 500_000_000


class Host:
    """A P controller u = r - y; records samples, sessions and late setpoints."""

    def __init__(self) -> None:
        self.started = False
        self.last_output = None
        self.stale_limit = 3
        self.now = 0
        self.ready = True
        self.samples: list[tuple[int, dict, dict, bool]] = []
        self.sessions: list[tuple[int, int]] = []
        self.late: list[tuple[int, list, list]] = []
        self.warnings: list[str] = []
        self.past: list[tuple[str, int, int]] = []

    def clock_ns(self):
        return self.now

    def sample(self, t_ns, y, r, d, stale, takeover=None):
        self.started = True
        self.samples.append((t_ns, dict(y), dict(r), stale))
        self.last_output = np.array([r['y'] - y['y']])
        return self.last_output

    def takeover(self, t_ns):
        return self.ready, None

    def accept(self, topic, values, names, last):
        out = {n: values[n] for n in names if n in values}
        last.update(out)
        return out

    def refused_past(self, topic, t_ns, held_ns):
        self.past.append((topic, t_ns, held_ns))

    def new_session(self, t_ns, last_ns):
        self.sessions.append((t_ns, last_ns))

    def late_setpoint(self, t_ns, names, used):
        self.late.append((t_ns, names, used))

    def info(self, text):
        pass

    def warning(self, text):
        self.warnings.append(text)


def make(cls, host, ts_ns=TS_NS, disturbances=()):
    future = FutureStamps(future_tolerance_ns(None, ts_ns / 1e9, cls.ticks))
    return cls(host, ts_ns, ('y',), disturbances, future)


def stamps(outputs):
    return [t for t, _ in outputs]


def test_the_mode_and_trigger_pick_the_protocol_once():
    assert controller_clock('lockstep', 'timer') is LockstepClock
    assert controller_clock('sim', 'measurement') is SimClock
    assert controller_clock('wall', 'timer') is WallTimerClock
    assert controller_clock('wall', 'measurement') is WallArrivalClock
    assert resolved_mode('auto', True) == 'lockstep' and resolved_mode('auto', False) == 'wall'
    assert not LockstepClock.sample_timer and SimClock.sample_timer
    # what /diagnostics reports as the trigger: in lockstep the `trigger` parameter (wall
    # only) does not apply; the plant's tick does
    assert (LockstepClock.trigger, SimClock.trigger, WallTimerClock.trigger,
            WallArrivalClock.trigger) == ('tick', 'timer', 'timer', 'measurement')


def test_lockstep_answers_a_tick_once_its_inputs_are_in_and_a_resent_one_identically():
    host = Host()
    clock = make(LockstepClock, host, ts_ns=100_000_000)
    assert clock.measurement(0, {'y': 1.0}) == []                # no setpoint yet
    [(t, u)] = clock.setpoint(0, {'y': 3.0})
    assert t == 0 and u.tolist() == [2.0] and len(host.samples) == 1
    again = clock.measurement(0, {'y': 1.0})                     # the plant re-sent tick 0
    assert stamps(again) == [0] and again[0][1] is u and len(host.samples) == 1
    assert clock.setpoint(0, {'y': 3.0}) == []                   # answered already
    # the setpoint stamped ahead (zero-order hold) answers the ticks up to its stamp
    clock.setpoint(300_000_000, {'y': 5.0})
    assert stamps(clock.measurement(100_000_000, {'y': 1.0})) == [100_000_000]
    assert stamps(clock.measurement(200_000_000, {'y': 1.0})) == [200_000_000]
    assert clock.measurement(100_000_000, {'y': 1.0}) == []      # a late duplicate
    assert host.sessions == [] and len(host.samples) == 3


def test_lockstep_holds_the_output_between_samples_of_a_slower_controller():
    host = Host()
    clock = make(LockstepClock, host, ts_ns=200_000_000)
    clock.setpoint(0, {'y': 3.0})
    clock.setpoint(1_000_000_000, {'y': 3.0})                    # known through 1 s
    outputs = [clock.measurement(k * 100_000_000, {'y': float(k)}) for k in range(5)]
    assert [o[0][1].tolist() for o in outputs] == [[3.0], [3.0], [1.0], [1.0], [-1.0]]
    assert [s[0] for s in host.samples] == [0, 200_000_000, 400_000_000]


def test_lockstep_a_restarted_plant_is_answered_from_tick_0_again():
    host = Host()
    clock = make(LockstepClock, host, ts_ns=100_000_000)
    clock.setpoint(0, {'y': 3.0})
    clock.setpoint(1_000_000_000, {'y': 3.0})
    for k in range(3):
        assert stamps(clock.measurement(k * 100_000_000, {'y': 0.0})) == [k * 100_000_000]
    clock.setpoint(0, {'y': 4.0})                                # the new run's reference
    assert stamps(clock.measurement(0, {'y': 0.0})) == [0]
    assert host.sessions == [(0, 200_000_000)] and host.samples[-1][2] == {'y': 4.0}


def test_lockstep_waits_for_the_take_over_values_then_answers():
    host = Host()
    host.ready = False
    clock = make(LockstepClock, host, ts_ns=100_000_000)
    clock.setpoint(0, {'y': 3.0})
    assert clock.measurement(0, {'y': 1.0}) == [] and host.samples == []
    host.ready = True
    assert stamps(clock.applied()) == [0]


def test_sim_samples_on_the_simulated_clock_grid_once_per_instant():
    """/clock moves in steps of 0.35 s, so the 0.5 s timer runs late by 0.2, 0.05, 0.25, ...
    s (as on a loaded machine); it may also run twice at one instant: each sample is stamped
    with the grid instant reached, one per instant, strictly increasing."""
    host = Host()
    clock = make(SimClock, host)
    out = []
    for k in range(1, 30):
        host.now = k * 350_000_000
        clock.measurement(host.now, {'y': 1.0})
        clock.setpoint(host.now, {'y': 3.0})
        out += clock.timer() + clock.timer()
    assert all(t % TS_NS == 0 for t in stamps(out))
    assert all(b > a for a, b in zip(stamps(out), stamps(out)[1:])), stamps(out)
    assert len(out) == len({k * 350 // 500 for k in range(1, 30)}) and out[-1][1].tolist() == [2.0]


def test_sim_reports_a_setpoint_that_came_after_its_sample():
    host = Host()
    clock = make(SimClock, host)
    clock.setpoint(0, {'y': 10.0})
    for k in range(1, 5):
        host.now = k * TS_NS
        clock.measurement(host.now, {'y': 0.0})
        assert stamps(clock.timer()) == [host.now]
        clock.setpoint(host.now, {'y': 10.0 + k})                 # after the sample
        assert host.late[-1] == (host.now, ['y'], [10.0 + k - 1 if k > 1 else 10.0])
    assert len(host.late) == 4


def test_sim_a_measurement_from_before_the_last_is_a_new_plant_session():
    host = Host()
    clock = make(SimClock, host)
    clock.measurement(3 * TS_NS, {'y': 0.0})
    clock.measurement(0, {'y': 0.0})
    assert host.sessions == [(0, 3 * TS_NS)]


def test_wall_on_arrival_answers_each_new_instant_with_the_measurement_s_stamp():
    host = Host()
    clock = make(WallArrivalClock, host, ts_ns=200_000_000)
    origin = 10_000_000_000
    assert clock.measurement(origin, {'y': 1.0}) == []           # no time origin yet
    clock.origin(origin)
    clock.setpoint(origin, {'y': 3.0})
    out = [clock.measurement(origin + k * 100_000_000, {'y': 1.0}) for k in range(1, 6)]
    # the controller is slower than the plant: only a new instant of its own grid samples
    assert [stamps(o) for o in out] == [[origin + 100_000_000], [origin + 200_000_000], [],
                                        [origin + 400_000_000], []]
    assert [s[0] for s in host.samples] == [100_000_000, 200_000_000, 400_000_000]


def test_wall_on_arrival_a_setpoint_ahead_of_its_instant_waits_for_it():
    host = Host()
    clock = make(WallArrivalClock, host, ts_ns=100_000_000)
    clock.origin(0)
    clock.setpoint(0, {'y': 3.0})
    clock.setpoint(200_000_000, {'y': 5.0})                       # wall.lead early
    clock.measurement(100_000_000, {'y': 0.0})
    clock.measurement(200_000_000, {'y': 0.0})
    assert [s[2]['y'] for s in host.samples] == [3.0, 5.0]


def test_wall_on_arrival_outputs_never_go_back_when_a_new_session_s_grid_lags():
    """The fail-safe (stale) sample of the timer at the latest instant; a restarted plant's
    first instants before it are not sampled (the outputs' stamps never go back)."""
    host = Host()
    clock = make(WallArrivalClock, host, ts_ns=100_000_000)
    clock.origin(0)
    clock.setpoint(0, {'y': 3.0})
    clock.measurement(100_000_000, {'y': 0.0})
    host.now = 1_000_000_000
    stale = []
    for _ in range(4):                                          # no measurement: stale
        host.now += 100_000_000
        stale += clock.timer()
    assert stamps(stale) == [1_300_000_000, 1_400_000_000] and host.samples[-1][3]
    clock.origin(1_250_000_000)                                 # a new plant session
    assert clock.measurement(1_350_000_000, {'y': 0.0}) == []   # behind the last output
    assert stamps(clock.measurement(1_450_000_000, {'y': 0.0})) == [1_450_000_000]


def test_wall_timer_samples_on_its_timer_and_passes_stale():
    host = Host()
    clock = make(WallTimerClock, host, ts_ns=100_000_000)
    host.now = 50
    assert clock.timer() == []                                  # no origin, nothing measured
    clock.origin(0)
    clock.setpoint(0, {'y': 3.0})
    clock.measurement(0, {'y': 1.0})
    host.now = 100_000_007
    assert stamps(clock.timer()) == [100_000_007] and not host.samples[-1][3]
    for _ in range(3):
        clock.timer()
    assert host.samples[-1][3]                                  # 3 timer calls without one


class P2(Host):
    """u = 2·(r − y) (a P-only PID with kp 2 after a warm start at y = r)."""

    def sample(self, t_ns, y, r, d, stale, takeover=None):
        super().sample(t_ns, y, r, d, stale, takeover)
        self.last_output = np.array([2.0 * (r['y'] - y['y'])])
        return self.last_output


def test_wall_measurement_trigger_answers_each_measurement_with_its_stamp():
    """trigger: measurement: each measurement that reaches a new instant of the controller's
    grid (origin + j·sample_time) is answered at once, stamped with the measurement's stamp and
    computed from it; one of the same instant, a duplicate or an older one is not. A plant
    ticking twice per controller sample; a setpoint published ahead waits for its instant."""
    host = P2()
    tick = 100_000_000
    clock = make(WallArrivalClock, host, ts_ns=2 * tick)
    origin = 1_700_000_000_000_000_000
    host.now = origin + 60 * tick
    assert clock.trigger == 'measurement'
    clock.origin(origin)
    clock.setpoint(origin, {'y': 1.0})
    out = clock.measurement(origin, {'y': 1.0})
    clock.setpoint(origin + 6 * tick, {'y': 2.0})              # ahead of its instant
    for k, y in ((1, 0.0), (2, 0.5), (5, 0.25), (5, 0.0), (4, 0.0), (6, 0.75)):
        out += clock.measurement(origin + k * tick, {'y': y})
    assert [t - origin for t, _ in out] == [0, 2 * tick, 5 * tick, 6 * tick]
    assert [u[0] for _, u in out] == [0.0, 1.0, 1.5, 2.5]
    assert not any(s[3] for s in host.samples)                  # none stale


def test_wall_outputs_never_go_back_when_a_restarted_plant_s_grid_lags():
    """A new plant session (a new time origin) whose first ticks are stamped before the
    controller's last output: those ticks are not sampled; the outputs' stamps only increase."""
    host = P2()
    ts = 100_000_000
    clock = make(WallArrivalClock, host, ts_ns=ts)
    old = 1_700_000_000_000_000_000
    clock.origin(old)
    clock.setpoint(old, {'y': 1.0})
    out = clock.measurement(old, {'y': 0.5})
    last = old + 100 * ts
    host.now = last
    out += clock.measurement(last, {'y': 0.5})
    new = last - 5 * ts - ts // 2          # the new session's tick 0, before that output
    clock.origin(new)
    for k in (1, 5):                       # before the last output: not samples
        assert clock.measurement(new + k * ts, {'y': 0.25}) == []
    out += clock.measurement(new + 6 * ts, {'y': 0.75})   # after it
    stamps_ = [t for t, _ in out]
    assert all(b > a for a, b in zip(stamps_, stamps_[1:])) and stamps_[-2:] == [last, new + 6 * ts]


def test_wall_an_origin_far_ahead_is_held_until_measurements_come_on_its_time_base():
    """An origin an hour ahead of the controller's clock is refused (a stray one would stop
    the loop); the plant's measurements on the held origin go on being answered. Once a
    measurement stamped on or after the refused origin is admitted (the plant restarted on a
    host whose clock is ahead: FutureStamps took its clock step), that origin is the loop's."""
    host = Host()
    clock = make(WallArrivalClock, host, ts_ns=100_000_000)
    origin, hour = 10_000_000_000, 3600 * 1_000_000_000
    host.now = origin
    clock.origin(origin)
    clock.setpoint(origin, {'y': 3.0})
    clock.origin(origin + hour)                                  # refused, held back
    assert clock.origin_ns == origin and host.warnings
    host.now = origin + 100_000_000
    assert stamps(clock.measurement(origin + 100_000_000, {'y': 1.0})) == [origin + 100_000_000]
    assert clock.origin_ns == origin                             # its own plant's: kept
    step = origin + hour + 200_000_000                           # admitted by the clock step
    clock.setpoint(step, {'y': 3.0})
    assert stamps(clock.measurement(step, {'y': 1.0})) == [step]
    assert clock.origin_ns == origin + hour and host.samples[-1][0] == 200_000_000


def test_lockstep_a_setpoint_stamped_before_the_ticks_answered_is_refused_and_reported():
    """An unstamped setpoint (``ros2 topic pub`` without ``header: auto``) on a running loop:
    those ticks are answered; it is reported (``refused_past``: counted, logged) when the
    loop goes on, and never acts on a later tick — the reference's values do."""
    host = Host()
    clock = make(LockstepClock, host, ts_ns=100_000_000)
    clock.setpoint(0, {'y': 3.0})
    clock.setpoint(1_000_000_000, {'y': 3.0})                    # known through 1 s
    for k in range(3):
        assert stamps(clock.measurement(k * 100_000_000, {'y': 0.0})) == [k * 100_000_000]
    assert clock.setpoint(0, {'y': 1.0}) == [] and host.past == []   # decided on the next tick
    assert stamps(clock.measurement(300_000_000, {'y': 0.0})) == [300_000_000]
    assert host.past == [('setpoint', 0, 200_000_000)]
    assert [s[2]['y'] for s in host.samples] == [3.0] * 4 and host.sessions == []
    # a disturbance stamped in the past likewise
    clock = make(LockstepClock, host, ts_ns=100_000_000, disturbances=('d',))
    clock.setpoint(0, {'y': 3.0})
    clock.setpoint(1_000_000_000, {'y': 3.0})
    clock.disturbance(0, {'d': 0.5})
    clock.disturbance(1_000_000_000, {'d': 0.5})
    for k in range(2):
        clock.measurement(k * 100_000_000, {'y': 0.0})
    clock.disturbance(0, {'d': 9.0})
    assert stamps(clock.measurement(200_000_000, {'y': 0.0})) == [200_000_000]
    assert host.past[-1] == ('disturbance', 0, 100_000_000)


def test_lockstep_a_restarted_plant_s_setpoint_that_came_first_is_taken_not_refused():
    """The new session's reference message may come before the plant's tick 0: it waits for
    it and is taken (answered from tick 0 again), never counted as refused."""
    host = Host()
    clock = make(LockstepClock, host, ts_ns=100_000_000)
    clock.setpoint(0, {'y': 3.0})
    clock.setpoint(1_000_000_000, {'y': 3.0})
    for k in range(3):
        clock.measurement(k * 100_000_000, {'y': 0.0})
    clock.setpoint(0, {'y': 4.0})
    clock.setpoint(100_000_000, {'y': 5.0})                      # both before tick 200 ms
    assert stamps(clock.measurement(0, {'y': 0.0})) == [0]
    assert stamps(clock.measurement(100_000_000, {'y': 0.0})) == [100_000_000]
    assert host.past == [] and host.sessions == [(0, 200_000_000)]
    assert [s[2]['y'] for s in host.samples[-2:]] == [4.0, 5.0]


def test_wall_and_sim_a_setpoint_older_than_the_one_held_is_refused_and_reported():
    """wall and sim keep the newest setpoint; an older (or unstamped) one is not taken and is
    reported (``refused_past``), not as a late setpoint; the value held goes on."""
    for cls in (WallTimerClock, WallArrivalClock, SimClock):
        host = Host()
        clock = make(cls, host, ts_ns=100_000_000)
        clock.origin(0)
        host.now = 1_000_000_000
        clock.setpoint(host.now, {'y': 3.0})
        clock.measurement(host.now, {'y': 0.0})
        clock.timer()
        assert clock.setpoint(0, {'y': 1.0}) == []                   # unstamped: refused
        assert host.past == [('setpoint', 0, 1_000_000_000)], cls
        assert host.late == []
        host.now = 1_100_000_000
        clock.measurement(host.now, {'y': 0.0})
        clock.timer()
        assert [s[2]['y'] for s in host.samples] == [3.0, 3.0], cls
