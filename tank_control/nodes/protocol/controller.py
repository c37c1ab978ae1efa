"""The controller's clock protocol (docs/nodes.md, "controller_node"), without rclpy.

``controller_clock(mode, trigger)`` picks the class once: ``LockstepClock`` answers each plant
tick, ``SimClock`` samples on a ``/clock`` timer, ``WallTimerClock`` on a wall timer and
``WallArrivalClock`` on each measurement's arrival (its timer only watches for stale ones).
The node feeds them the stamped inputs it has parsed; each call returns the outputs to publish
as ``(stamp_ns, u)``. What a sample computes (warm start, faults, take-over) is the host's
(``ControllerHost``). Times in integer ns.
"""
from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

import numpy as np

from tank_control.core.stamps import PAST_FIX_SIM, PAST_FIX_WALL, FutureStamps, origin_refusal
from tank_control.nodes.clock import (Answers, Scheduled, StampedInbox, is_sample_instant,
                                      sim_sample_instant)

#: the input topics (as nodes/messages.py names them)
MEASUREMENT, SETPOINT, DISTURBANCE = 'measurement', 'setpoint', 'disturbance'

Outputs = list[tuple[int, np.ndarray]]


class ControllerHost(Protocol):
    """What the protocol asks of the node: the sample itself and the node's side effects."""

    @property
    def started(self) -> bool: ...          # the first good sample is done

    @property
    def last_output(self) -> np.ndarray | None: ...

    @property
    def stale_limit(self) -> int: ...

    def clock_ns(self) -> int: ...

    def sample(self, t_ns: int, y: Mapping[str, float], r: Mapping[str, float],
               d: Mapping[str, float], stale: bool,
               takeover: np.ndarray | None = None) -> np.ndarray: ...

    def takeover(self, t_ns: int) -> tuple[bool, np.ndarray | None]: ...

    def accept(self, topic: str, values: Mapping[str, float], names: tuple[str, ...],
               last: dict[str, float]) -> dict[str, float]: ...

    def new_session(self, t_ns: int, last_ns: int) -> None: ...

    def late_setpoint(self, t_ns: int, names: list[str], used: list[float]) -> None: ...

    def refused_past(self, topic: str, t_ns: int, held_ns: int) -> None: ...

    def info(self, text: str) -> None: ...

    def warning(self, text: str) -> None: ...


class ControllerClock:
    """Common state: the latest inputs and the plant's time base."""

    mode = ''
    trigger = 'timer'
    ticks = False            # stamps are plant ticks (lockstep): core/stamps tolerance
    sample_timer = True      # the node runs a timer of the sample time calling ``timer``
    real_time = False        # samples on the wall clock: costly work runs off the sampling path
    # a setpoint/disturbance refused for its stamp (``refused_past``): older than what, and
    # what the user does about it (the node's log line)
    past_held = 'the setpoint held'
    past_fix = PAST_FIX_WALL

    def __init__(self, host: ControllerHost, ts_ns: int, outputs: tuple[str, ...],
                 disturbances: tuple[str, ...], future: FutureStamps) -> None:
        self.host, self.ts_ns, self.future = host, ts_ns, future
        self.outputs, self.disturbances = outputs, disturbances
        self.y: dict[str, float] = {}
        self.r: dict[str, float] = {}
        # measured disturbances: a channel never received is passed as NaN, and the
        # controller substitutes its own value (mpcs: the operating point mpcs.op.F_D/T_D)
        self.d: dict[str, float] = {name: float('nan') for name in disturbances}
        # plant time base: origin of the stamps (wall: from the plant, None until then)
        self.origin_ns: int | None = 0

    # what the node asks
    def now_ns(self) -> int | None:
        """This node's now in the stamps' time base (None: not known yet)."""
        return self.host.clock_ns()

    def measurement_tolerance_ns(self) -> int | None:
        """How far ahead of now a measurement may be stamped (None: the node's tolerance)."""
        return None

    def waiting_for_measurement(self) -> bool:
        return len(self.y) < len(self.outputs)

    # inputs: each returns the outputs to publish
    def measurement(self, t_ns: int, values: dict[str, float]) -> Outputs:
        raise NotImplementedError

    def setpoint(self, t_ns: int, values: Mapping[str, float]) -> Outputs:
        raise NotImplementedError

    def disturbance(self, t_ns: int, values: Mapping[str, float]) -> Outputs:
        raise NotImplementedError

    def origin(self, origin_ns: int) -> bool:
        """The plant's ``time_origin``; True when it conflicts with this clock mode (a plant
        on the wall clock, which publishes no /clock ticks to answer)."""
        return origin_ns != 0

    def applied(self) -> Outputs:
        """The plant's ``applied_input`` came (before the first sample)."""
        return []

    def timer(self) -> Outputs:
        return []


class LockstepClock(ControllerClock):
    """Answer each plant tick once its inputs are complete (idempotent: a re-sent tick gets
    the same answer). The reference's topics are zero-order-hold streams (``clock.Held``)."""

    mode = 'lockstep'
    trigger = 'tick'         # /diagnostics: a sample is a plant tick's inputs complete
    past_held = 'the tick already answered'
    past_fix = ('change the reference (its parameters) instead: lockstep inputs come from the '
                'reference_node')
    ticks = True
    sample_timer = False

    def __init__(self, host: ControllerHost, ts_ns: int, outputs: tuple[str, ...],
                 disturbances: tuple[str, ...], future: FutureStamps) -> None:
        super().__init__(host, ts_ns, outputs, disturbances, future)
        required: dict[str, tuple[str, ...]] = {MEASUREMENT: outputs, SETPOINT: outputs}
        if disturbances:
            required[DISTURBANCE] = ()   # arrival is enough; missing channels keep last values
        self.inbox = StampedInbox(required, held=(SETPOINT, DISTURBANCE))
        self.measured_ns: int | None = None   # the latest measurement's stamp
        self.behind_ns: int | None = None     # a tick seen before the last answered
        self.answers = Answers()               # the last tick answered: (u,)
        self.deferred_tick: int | None = None  # waits for the plant's applied_input
        # setpoints/disturbances stamped before the last tick answered: a restarted plant's
        # (taken when its tick 0 comes) or stale (refused at the next measurement)
        self.past: list[tuple[str, int, Mapping[str, float]]] = []

    def now_ns(self) -> int | None:
        return self.measured_ns

    def measurement_tolerance_ns(self) -> int | None:
        # the plant publishes tick k+1 only once tick k is answered, so a measurement is at
        # most one plant tick (<= this controller's sample time) past the latest one
        return self.ts_ns

    def waiting_for_measurement(self) -> bool:
        return self.measured_ns is None          # no plant tick yet

    def measurement(self, t_ns: int, values: dict[str, float]) -> Outputs:
        self._check_new_session(t_ns)
        self._settle_past(t_ns)
        self.inbox.put(MEASUREMENT, t_ns, values)   # non-finite kept: the sample handles it
        self.measured_ns = t_ns
        return self._maybe_answer(t_ns, resent=True)

    def setpoint(self, t_ns: int, values: Mapping[str, float]) -> Outputs:
        return self._held_input(SETPOINT, t_ns, values)

    def disturbance(self, t_ns: int, values: Mapping[str, float]) -> Outputs:
        return self._held_input(DISTURBANCE, t_ns, values)

    #: the most setpoint/disturbance messages stamped in the past held until the next
    #: measurement decides on them (a restarted reference's first look-ahead fits easily)
    PAST_LIMIT = 64

    def _held_input(self, topic: str, t_ns: int, values: Mapping[str, float]) -> Outputs:
        """A setpoint or disturbance: one stamped before the last tick answered cannot act
        on the running session (those ticks are answered); it waits for the next measurement
        (``_settle_past``): a restarted plant's tick 0 takes it, else it is refused."""
        answered = self.answers.stamp
        if answered is not None and t_ns < answered:
            self.past.append((topic, t_ns, dict(values)))
            if len(self.past) > self.PAST_LIMIT:
                old_topic, old_ns, _ = self.past.pop(0)
                self.host.refused_past(old_topic, old_ns, answered)
            return []
        self._put(topic, t_ns, values)
        return self._answer_measured()

    def _put(self, topic: str, t_ns: int, values: Mapping[str, float]) -> None:
        if topic == SETPOINT:
            self.inbox.put(SETPOINT, t_ns, self.host.accept(SETPOINT, values, self.outputs,
                                                            self.r))
        else:
            self.inbox.put(DISTURBANCE, t_ns, self.host.accept(DISTURBANCE, values,
                                                               self.disturbances, self.d))

    def _settle_past(self, t_ns: int) -> None:
        """A measurement of tick ``t_ns`` came: the inputs stamped in the past are taken
        when the answers start again (a new plant session), refused (``refused_past``) when
        the loop goes on at or after the last tick answered; kept while the plant re-sends a
        tick behind it (``_maybe_answer`` may start the answers again from it)."""
        answered = self.answers.stamp
        if not self.past or (answered is not None and t_ns < answered):
            return
        past, self.past = self.past, []
        for topic, stamp, values in past:
            if answered is None or stamp >= answered:
                self._put(topic, stamp, values)
            else:
                self.host.refused_past(topic, stamp, answered)

    def applied(self) -> Outputs:
        if self.deferred_tick is None:
            return []
        t_ns, self.deferred_tick = self.deferred_tick, None
        return self._maybe_answer(t_ns)

    def _check_new_session(self, t_ns: int) -> None:
        """A plant that (re)started: its tick 0 after later ticks. The old session's answers
        and inputs stamped at or after the last tick answered are dropped."""
        last = self.answers.stamp
        if t_ns != 0 or last is None or last <= 0:
            return
        self.answers = Answers()
        self.inbox.drop_from(last)
        self.deferred_tick = None
        self.host.new_session(t_ns, last)

    def _answer_measured(self) -> Outputs:
        """A setpoint or disturbance came (it may complete the latest tick measured; one
        stamped ahead holds for the ticks up to its stamp)."""
        if self.measured_ns is None:
            return []
        return self._maybe_answer(self.measured_ns)

    def _maybe_answer(self, t_ns: int, resent: bool = False) -> Outputs:
        """Answer tick ``t_ns`` once its inputs are complete (idempotent): a measurement of a
        tick already answered (the plant re-sent it) gets the same answer, not recomputed."""
        cached = self.answers.get(t_ns)
        if cached is not None:
            return [(t_ns, cached[0])] if resent else []
        if self.answers.stamp is not None and t_ns < self.answers.stamp:
            if not (resent and t_ns == self.behind_ns):
                self.behind_ns = t_ns if resent else self.behind_ns
                return []   # a late duplicate of a tick already passed
            # the plant re-sends a tick before the last one answered: it waits for it (the
            # later stamp answered was not its own); answered anew, as a new session
            self.host.warning(
                f'measurement {t_ns} ns re-sent after {self.answers.stamp} ns was answered: '
                'the plant waits for it; ticks answered from it again')
            self.answers = Answers()
            self.inbox.drop_from(t_ns + 1)
            self._settle_past(t_ns)
        if not self.inbox.complete(t_ns):
            return []
        y = self.inbox.values(t_ns, MEASUREMENT)
        r = self.inbox.values(t_ns, SETPOINT)
        d = {**self.d, **self.inbox.values(t_ns, DISTURBANCE)}
        takeover = None
        if not self.host.started:
            ready, takeover = self.host.takeover(t_ns)
            if not ready:
                self.deferred_tick = t_ns     # answered when applied_input comes (or re-sent)
                return []
        held = self.host.last_output
        if is_sample_instant(t_ns, self.ts_ns) or held is None:
            u = self.host.sample(t_ns, y, r, d, stale=False, takeover=takeover)
        else:
            u = held
        self.answers.remember(t_ns, u)
        self.inbox.drop_before(t_ns)
        return [(t_ns, u)]


class _Latest(ControllerClock):
    """wall and sim: sample the latest values (measurement, setpoint, disturbance)."""

    def __init__(self, host: ControllerHost, ts_ns: int, outputs: tuple[str, ...],
                 disturbances: tuple[str, ...], future: FutureStamps) -> None:
        super().__init__(host, ts_ns, outputs, disturbances, future)
        self.fresh = False                   # a whole measurement came since the last timer
        self.since_measurement = 0           # timer calls without one
        self.r_stamp: int | None = None      # stamp of the setpoint held
        self.last_y_stamp: int | None = None  # stamp of the latest measurement
        self.last_sample: tuple[int, dict[str, float]] | None = None   # (plant time, r used)

    def measurement(self, t_ns: int, values: dict[str, float]) -> Outputs:
        self._check_new_session(t_ns)
        self.y.update(values)
        if len(values) == len(self.outputs):
            self.fresh = True
            return self._arrived(t_ns)
        return []

    def _arrived(self, t_ns: int) -> Outputs:
        return []

    def _check_new_session(self, t_ns: int) -> None:
        """A measurement stamped before the previous one (sim: /clock went back; wall: a new
        plant session): the stamps of held values are dropped."""
        last = self.last_y_stamp
        self.last_y_stamp = t_ns
        if last is None or t_ns >= last:
            return
        self.r_stamp = None
        self.last_sample = None
        self.host.new_session(t_ns, last)

    def setpoint(self, t_ns: int, values: Mapping[str, float]) -> Outputs:
        if self.r_stamp is not None and t_ns < self.r_stamp:
            if not self.future.back_on_clock(SETPOINT, self.r_stamp, t_ns, self.now_ns()):
                # older than the setpoint held (out of order, or unstamped): not taken
                self.host.refused_past(SETPOINT, t_ns, self.r_stamp)
                return []
            self._clear_ahead()       # the stepped values waiting for their stamps
            for text in self.future.take_report():
                self.host.warning(text)
        self._check_late_setpoint(t_ns, values)
        self.r_stamp = t_ns
        self._take(SETPOINT, t_ns, values)
        return []

    def disturbance(self, t_ns: int, values: Mapping[str, float]) -> Outputs:
        self._take(DISTURBANCE, t_ns, values)
        return []

    def _take(self, topic: str, t_ns: int, values: Mapping[str, float]) -> None:
        """sim: the values act at once (last valid kept for a rejected one)."""
        if topic == SETPOINT:
            self.host.accept(topic, values, self.outputs, self.r)
        else:
            self.host.accept(topic, values, self.disturbances, self.d)

    def _clear_ahead(self) -> None:
        pass

    def _check_late_setpoint(self, t_ns: int, values: Mapping[str, float]) -> None:
        """A setpoint stamped at or before the latest sample came too late for it."""
        if self.last_sample is None or self.origin_ns is None:
            return
        sampled_at, r_used = self.last_sample
        if t_ns - self.origin_ns <= sampled_at:
            names = [n for n in self.outputs if n in values]
            self.host.late_setpoint(t_ns, names, [r_used.get(n, float('nan')) for n in names])

    def _ready(self) -> bool:
        """Something to control: measured, a setpoint, the plant's time origin known."""
        return (len(self.y) >= len(self.outputs) and len(self.r) >= len(self.outputs)
                and self.origin_ns is not None)

    def _stale(self) -> bool:
        """A timer call: count it, True when no measurement came for ``stale_samples``."""
        self.since_measurement = 0 if self.fresh else self.since_measurement + 1
        self.fresh = False
        return self.since_measurement >= self.host.stale_limit

    def _takeover(self, plant_ns: int) -> tuple[bool, np.ndarray | None]:
        """Before the first sample, the host's take-over; after it ``(True, None)``."""
        return (True, None) if self.host.started else self.host.takeover(plant_ns)

    def _sample(self, t_ns: int, stale: bool, takeover: np.ndarray | None) -> Outputs:
        """Sample at the absolute stamp ``t_ns`` (plant time ``t_ns - origin``)."""
        assert self.origin_ns is not None
        plant_ns = t_ns - self.origin_ns
        self.last_sample = (plant_ns, dict(self.r))
        u = self.host.sample(plant_ns, self.y, self.r, self.d, stale=stale, takeover=takeover)
        self.last_out_ns = t_ns
        return [(t_ns, u)]

    last_out_ns: int | None = None


class SimClock(_Latest):
    """sim: sample on a timer of the /clock time, stamped with the instant reached."""

    mode = 'sim'
    past_fix = PAST_FIX_SIM
    _instant: int | None = None         # the latest timer call's instant [ns]

    def now_ns(self) -> int | None:
        now = self.host.clock_ns()
        return None if now == 0 else now

    def timer(self) -> Outputs:
        """rclpy's EventsExecutor may run the timer twice at one instant (two clock updates
        queued before the timer's dispatch): an instant is sampled once. A /clock that goes
        back (a restarted plant) needs nothing here: rcl re-arms the timer one period after
        the new time."""
        instant = sim_sample_instant(self.host.clock_ns(), self.ts_ns)
        if instant == self._instant:
            return []
        self._instant = instant
        stale = self._stale()
        if not self._ready():
            return []          # nothing measured or no setpoint yet: nothing to control
        t_ns = sim_sample_instant(self.host.clock_ns(), self.ts_ns)
        ready, takeover = self._takeover(t_ns)
        if not ready:
            return []          # the plant's applied_input is on its way
        return self._sample(t_ns, stale, takeover)


class WallTimerClock(_Latest):
    """wall, ``trigger: timer``: sample on a wall timer; setpoint and disturbance values
    stamped ahead (the reference's ``wall.lead``) wait for their instant (``Scheduled``)."""

    mode = 'wall'
    real_time = True

    def __init__(self, host: ControllerHost, ts_ns: int, outputs: tuple[str, ...],
                 disturbances: tuple[str, ...], future: FutureStamps) -> None:
        super().__init__(host, ts_ns, outputs, disturbances, future)
        self.origin_ns = None
        self.refused_origins = 0                 # time_origin messages far ahead (origin())
        self.pending_origin: int | None = None   # the latest refused one (measurement())
        self.r_ahead, self.d_ahead = Scheduled(), Scheduled()
        self.r_valid: dict[str, float] = {}      # their last valid values
        self.d_valid: dict[str, float] = {}
        self.last_instant: int | None = None     # on arrival: index of the last sample
        # stamp of the last output published [ns]; a new plant session (new origin) may put
        # its first instants before it, and the outputs' stamps must not go back
        self.last_out_ns = None

    def origin(self, origin_ns: int) -> bool:
        """The loop's time base (a new one when the plant restarted); one far ahead of this
        node's clock is refused and counted (``core/stamps.origin_refusal``)."""
        reason = origin_refusal(origin_ns, self.origin_ns, self.host.clock_ns(),
                                self.future.tolerance_ns, self.ts_ns)
        if reason:
            self.future.refused += 1
            self.refused_origins += 1
            self.pending_origin = origin_ns
            if self.refused_origins in (1, 10, 100) or self.refused_origins % 1000 == 0:
                self.host.warning(f'{reason} ({self.refused_origins} so far); taken once a '
                                  'measurement on its time base is (a plant on a host whose '
                                  'clock is ahead: after the clock step)')
            return False
        self.pending_origin = None
        self._take_origin(origin_ns)
        return False

    def measurement(self, t_ns: int, values: dict[str, float]) -> Outputs:
        """A refused time origin is the loop's once a measurement stamped on or after it has
        been admitted (``FutureStamps`` took the measurements' clock step): a plant that
        restarted on a host whose clock is ahead. One a stray message announced never is:
        the plant's measurements stay on the held origin's time base."""
        pending = self.pending_origin
        if pending is not None and t_ns >= pending:
            self.pending_origin = None
            self.host.info(f'time_origin {pending} ns taken: the measurements came on its time '
                           'base (a clock step)')
            self._take_origin(pending, stepped=True)
        return super().measurement(t_ns, values)

    def _take_origin(self, origin_ns: int, stepped: bool = False) -> None:
        """A new time base; ``stepped``: the measurements' clock step that brought it is
        kept (else no clock offset is carried over)."""
        if origin_ns != self.origin_ns:
            self.host.info(f'plant time origin {origin_ns} ns: loop time = stamp - origin')
            self.origin_ns = origin_ns
            if not stepped:
                self.future.reset()
            self.last_sample = None
            self.last_instant = None

    def _take(self, topic: str, t_ns: int, values: Mapping[str, float]) -> None:
        if topic == SETPOINT:
            self.r_ahead.put(t_ns, self.host.accept(topic, values, self.outputs, self.r_valid))
        else:
            self.d_ahead.put(t_ns, self.host.accept(topic, values, self.disturbances,
                                                    self.d_valid))

    def _clear_ahead(self) -> None:
        self.r_ahead.clear()

    def _release_ahead(self, t_ns: int) -> None:
        """The setpoint and disturbance values stamped at or before ``t_ns`` (absolute)
        take effect (values published ahead of their instant wait until then)."""
        self.r_ahead.release(t_ns, self.r)
        self.d_ahead.release(t_ns, self.d)

    def timer(self) -> Outputs:
        stale = self._stale()
        self._release_ahead(self.host.clock_ns())
        if not self._ready():
            return []
        assert self.origin_ns is not None
        t_ns = self.host.clock_ns()
        ready, takeover = self._takeover(t_ns - self.origin_ns)
        if not ready:
            return []
        return self._sample(t_ns, stale, takeover)

    def _behind_last_output(self, t_ns: int) -> bool:
        """An output stamped ``t_ns`` would go back behind the last one (never published),
        unless that one is stamped beyond the tolerance ahead of this node's clock: it answered
        a stream taken through a clock step (core/stamps.py), whose clock has gone back since —
        waiting until real time passes it would hold the loop as long as the step was."""
        last = self.last_out_ns
        if last is None or t_ns > last:
            return False
        now = self.now_ns()
        return now is None or last - now <= self.future.tolerance_ns


class WallArrivalClock(WallTimerClock):
    """wall, ``trigger: measurement``: sample on each measurement's arrival — sample, compute
    and actuate in one cycle, so the plant's next tick holds the output computed from its last
    measurement (the discrete loop of core/loop.py, with a computation and transport delay
    instead of none). Only a measurement that reaches a new instant of this controller's grid,
    ``j = floor((t_ns - origin) / sample_time)``, is a sample (a controller slower than the
    plant, a duplicate, or one out of order is not), nor one stamped at or before the last
    output (a restarted plant's first instants may come before the last fail-safe sample of
    the stale period; the outputs' stamps never go back). The setpoint and disturbance are
    those stamped at or before ``t_ns``. The timer only samples a stale measurement (the
    fail-safe), on this controller's grid."""

    trigger = 'measurement'

    def _arrived(self, t_ns: int) -> Outputs:
        self._release_ahead(t_ns)
        if not self._ready():
            return []          # nothing measured or no setpoint yet: nothing to control
        assert self.origin_ns is not None
        if t_ns < self.origin_ns:
            return []          # an older session's
        instant = (t_ns - self.origin_ns) // self.ts_ns
        if self.last_instant is not None and instant <= self.last_instant:
            return []
        if self._behind_last_output(t_ns):
            return []
        ready, takeover = self._takeover(t_ns - self.origin_ns)
        if not ready:
            return []          # the plant's applied_input is on its way
        self.last_instant = instant
        self.since_measurement = 0
        self.fresh = False
        return self._sample(t_ns, False, takeover)

    def timer(self) -> Outputs:
        stale = self._stale()
        if not stale:
            return []          # sampled on the measurements' arrival; the timer only watches
        self._release_ahead(self.host.clock_ns())
        if not self._ready():
            return []
        assert self.origin_ns is not None
        now = self.host.clock_ns()
        instant = (now - self.origin_ns) // self.ts_ns
        if self.last_instant is not None and instant <= self.last_instant:
            return []
        t_ns = self.origin_ns + instant * self.ts_ns
        if self._behind_last_output(t_ns):
            return []          # the new session's grid lags the last output: its next instant
        self.last_instant = instant
        ready, takeover = self._takeover(t_ns - self.origin_ns)
        if not ready:
            return []          # the plant's applied_input is on its way
        return self._sample(t_ns, True, takeover)


_CLOCKS: dict[tuple[str, str], type[ControllerClock]] = {
    ('lockstep', 'timer'): LockstepClock, ('lockstep', 'measurement'): LockstepClock,
    ('sim', 'timer'): SimClock, ('sim', 'measurement'): SimClock,
    ('wall', 'timer'): WallTimerClock, ('wall', 'measurement'): WallArrivalClock}


def resolved_mode(clock_mode: str, use_sim_time: bool) -> str:
    """``clock_mode`` with ``auto`` resolved: the harness passes use_sim_time in sim and
    lockstep, where a controller answers the plant's ticks (lockstep)."""
    if clock_mode != 'auto':
        return clock_mode
    return 'lockstep' if use_sim_time else 'wall'


def controller_clock(mode: str, trigger: str) -> type[ControllerClock]:
    """The protocol class of clock ``mode`` (wall, sim, lockstep) and ``trigger``
    (measurement, timer: wall only)."""
    return _CLOCKS[mode, trigger]
