"""The plant's clock protocol (docs/nodes.md, "Clock modes"), without rclpy: the clock master.

``plant_clock(mode)`` picks the class once: ``LockstepPlant`` publishes tick k and integrates
once every answer of it is in (re-sending it until then, pacing and the recorder's window);
``SimPlant`` steps on a timer of wall time / ``real_time_factor``; ``WallPlant`` on the wall
clock's grid from an announced time origin. Each holds the model's inputs and tick and asks
its host (the node) to publish the CDR bytes it made and to make the timers it needs
(``PlantHost``). Times in integer ns unless named ``_s``.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from tank_control.core.interfaces import seconds, to_ns
from tank_control.core.loop import nominal_disturbances, nominal_inputs
from tank_control.core.stamps import PAST_FIX_SIM, PAST_FIX_WALL, FutureStamps
from tank_control.nodes.cdr import JointStateCdr, clock_cdr_ns
from tank_control.nodes.clock import Scheduled, StampedInbox

#: the input topics (as nodes/messages.py names them) and who answers them (the stall report)
MANIPULATED, DISTURBANCE = 'manipulated', 'disturbance'
_ANSWERED_BY = {MANIPULATED: 'controller', DISTURBANCE: 'reference'}
_LOOKAHEAD = 8   # lockstep: answers up to this many ticks ahead are kept (lockstep.lookahead <= 8)
#: sim/wall: the inputs integrated over this many latest ticks are remembered, for the values a
#: late answer's report names (~/late_inputs; an answer later than that reports nan)
_LATE_MEMORY = 1000
#: lockstep: a tick unanswered for this many ``lockstep.resend_period`` is a stall (WARN)
STALL_RESENDS = 2
#: wall/sim: ``manipulated`` silent for this many of its recent intervals (and at least
#: ``STALL_MIN_S``) is a stall (WARN; the inputs are held)
STALL_INTERVALS = 3
STALL_MIN_S = 1.0
#: wall/sim: an input topic that has sent nothing this long after the first tick is reported
#: as awaited (WARN; the inputs keep their initial values) [s of wall time]
NEVER_RECEIVED_S = 3.0
#: wall: the time origin (tick 0) is announced this long ahead, rounded up to whole periods:
#: the reference's instant 0 and its ``wall.lead`` fit in it with room for a loaded machine [s]
ORIGIN_NOTICE_S = 0.2


class Timer(Protocol):
    """What the protocol does with a timer the host made (an rclpy timer)."""

    timer_period_ns: int

    def cancel(self) -> None: ...

    def reset(self) -> None: ...


class PlantHost(Protocol):
    """The node's side: publishers, timers, the graph, parameters, the log."""

    @property
    def paused(self) -> bool: ...            # lockstep.paused

    @property
    def real_time_factor(self) -> float: ...

    def timer(self, period_s: float, callback: Callable[[], None],
              autostart: bool = True) -> Timer: ...

    def destroy(self, timer: Timer) -> None: ...

    def publish_measurement(self, msg: bytes) -> None: ...

    def publish_clock(self, msg: bytes) -> None: ...

    def publish_applied(self, msg: bytes) -> None: ...

    def publish_origin(self, origin_ns: int) -> None: ...

    def measured(self, stamp_ns: int, y: np.ndarray) -> None: ...   # the tick's values

    def publish_late(self, t_ns: int, names: list[str], values: list[float]) -> None: ...

    def ros_now_ns(self) -> int: ...

    def match_wait(self) -> bool: ...

    def apply_pending(self) -> None: ...

    def warning(self, text: str) -> None: ...


class PlantClock:
    """Common state: the model, its held inputs, tick k, the applied inputs, stall watch."""

    mode = ''
    ticks = False            # stamps are plant ticks (lockstep): core/stamps tolerance
    publishes_clock = True   # /clock
    prestart_reports = True  # /diagnostics every 20 ms before tick 0 (the harness waits)
    real_time = False        # ticks on the wall clock: its stamps are wall-clock times

    def __init__(self, host: PlantHost, plant: Any, noise: Any, values: Mapping[str, Any],
                 counters: dict[str, int], future: FutureStamps, session: str) -> None:
        self.host, self.plant, self.noise = host, plant, noise
        self.counters, self.future, self.session = counters, future, session
        self.ts = float(values['sample_time'])
        self.ts_ns = to_ns(self.ts)
        self.k = 0
        self.u = nominal_inputs(plant)
        self.d = nominal_disturbances(plant)
        self.stamp_offset_ns = 0           # the time origin (wall: set at tick 0)
        self.announced = False             # wall: the time origin is published
        self.tick_msgs: tuple[bytes, bytes | None] | None = None   # CDR: measurement, /clock
        self.resend_period = float(values['lockstep.resend_period'])
        self.awaiting = False
        self.sent_at = 0.0
        # hot-path messages as pre-encoded CDR (nodes/cdr.py): measurement, applied_input
        self._measurement_cdr = JointStateCdr(plant.output_names, session)
        self._applied_names: list[str] = []
        self._applied_sent: tuple[float, ...] | None = None
        self._applied_cdr = JointStateCdr((), session)
        # stall watch: wall time tick k was first published (lockstep); per input topic the
        # last arrival and the interval before it (wall/sim) [s, time.monotonic]
        self.tick_published_at = time.monotonic()
        self.first_tick_at: float | None = None
        self.arrivals: dict[str, tuple[float, float]] = {}
        self.step_s = 0.0                  # computation time of plant.step since the report
        self.steps = 0
        self._pace_mark: tuple[float, int] | None = None   # (wall s, tick) at the last report
        self.past_logged: set[str] = set()   # sim/wall: topics refused for their stamp, logged

    def t(self) -> float:
        return seconds(self.k * self.ts_ns)

    def start(self) -> None:
        """At start-up, not paused: tick 0 right away (lockstep: re-sent until answered)."""
        self.host.publish_origin(0)        # the simulated clock starts at 0
        if not self.host.paused:
            self.publish_tick()

    def empty_applied(self) -> bytes:
        return self._applied_cdr.encode_ns(0, ())

    # ----------------------------------------------------------------- ticks
    def publish_tick(self) -> None:
        """Measure tick k (one noise draw), publish measurement (+ /clock)."""
        t_ns = self.k * self.ts_ns
        y = self.plant.outputs() + self.noise.sample()
        stamp = self.stamp_offset_ns + t_ns
        msg = self._measurement_cdr.encode_ns(stamp, y)
        clock = clock_cdr_ns(t_ns) if self.publishes_clock else None
        self.tick_msgs = (msg, clock)
        self.send()
        self.host.measured(stamp, y)
        self.tick_published_at = self.sent_at
        if self.first_tick_at is None:
            self.first_tick_at = self.sent_at
        self.counters['ticks'] += 1
        self.awaiting = self.ticks

    def send(self) -> None:
        assert self.tick_msgs is not None
        msg, clock = self.tick_msgs
        # sim: the measurement of t_k must be in before /clock fires the others' timers.
        self.host.publish_measurement(msg)
        if clock is not None:
            self.host.publish_clock(clock)
        self.sent_at = time.monotonic()

    def step(self) -> None:
        """Integrate [t_k, t_k+1) with the held inputs, k += 1."""
        self.host.apply_pending()
        self._before_step()
        start = time.perf_counter()
        self.plant.step(np.array([self.u[n] for n in self.plant.input_names]),
                        np.array([self.d[n] for n in self.plant.disturbance_names]), self.ts)
        self.step_s += time.perf_counter() - start
        self.steps += 1
        self.k += 1

    def _before_step(self) -> None:
        pass

    def publish_applied(self, tick: int) -> None:
        """``applied_input``: the manipulated values of step ``tick`` (channels a controller
        has sent), stamped with it, when they changed. wall/sim: at every step. lockstep: only
        when the loop stops — tick k re-sent (its answers did not come: a controller may be
        restarting) or paused — with the values of the last step integrated, k−1: a running
        controller never reads them, and a starting one reads the latched message."""
        if not self._applied_names or tick < 0:
            return
        values = tuple(self.u[n] for n in self._applied_names)
        if values != self._applied_sent:
            self._applied_sent = values
            self.host.publish_applied(self._applied_cdr.encode_ns(
                self.stamp_offset_ns + tick * self.ts_ns, values))

    def note_applied(self, names: Any) -> None:
        """Channels of ``manipulated`` received from a controller (in the plant's order)."""
        if any(n not in self._applied_names for n in names):
            known = set(self._applied_names) | set(names)
            self._applied_names = [n for n in self.plant.input_names if n in known]
            self._applied_cdr = JointStateCdr(self._applied_names, self.session)

    # ---------------------------------------------------------------- inputs
    def now_ns(self) -> int | None:
        """This plant's now in the stamps' time base: sim/lockstep the current tick."""
        return self.k * self.ts_ns

    def input(self, topic: str, t_ns: int, names: tuple[str, ...], accepted: dict[str, float],
              known: tuple[str, ...]) -> None:
        """An admitted input message (``accepted``: its valid known values)."""
        now = time.monotonic()
        last = self.arrivals.get(topic)
        self.arrivals[topic] = (now, now - last[0] if last else 0.0)
        self._take(topic, t_ns, names, accepted, known)

    def _take(self, topic: str, t_ns: int, names: tuple[str, ...], accepted: dict[str, float],
              known: tuple[str, ...]) -> None:
        raise NotImplementedError

    # ------------------------------------------------------- parameters, pause
    window = 0                             # lockstep.record_window (lockstep only)

    def recorded(self, stamp_ns: int) -> None:
        """The recorder acknowledged the ticks up to ``stamp_ns`` (lockstep)."""

    def start_clock(self) -> None:
        """Start (or, un-paused, restart) the tick timer (sim, wall)."""

    def set_rtf(self, rtf: float) -> None:
        """A new ``real_time_factor`` (sim, lockstep)."""

    def set_paused(self, paused: bool, was_paused: bool, unpaused: bool) -> None:
        """``lockstep.paused`` changed (``unpaused``: set to false in this request)."""

    def pause_refused(self, paused: bool) -> str | None:
        """Why ``lockstep.paused: paused`` is refused now (None: accepted)."""
        return None

    # ----------------------------------------------------------- diagnostics
    def pace_report(self) -> str:
        """'' while simulated time keeps its pace, else how far behind it is (measured over
        the time since the last report); also takes the mean step time."""
        now, mark = time.monotonic(), self._pace_mark
        self._pace_mark = None if self.host.paused else (now, self.k)
        step_ms = self.step_s / self.steps * 1e3 if self.steps else 0.0
        self.step_s, self.steps = 0.0, 0
        self.step_ms = step_ms
        target = self._pace_target()
        if target is None or self.host.paused or mark is None or now - mark[0] < 0.5:
            return ''
        rate = (self.k - mark[1]) * self.ts / (now - mark[0])
        if rate >= 0.9 * target:
            return ''
        return (f'behind real time: {rate:.3g}x instead of {target:g}x (plant.step takes '
                f'{step_ms:.3g} ms per {self.ts * 1e3:g} ms tick)')

    step_ms = 0.0                          # the mean step time over the last report [ms]

    def _pace_target(self) -> float | None:
        return None

    def stall_report(self) -> str:
        return ''

    def waiting_for(self) -> str | None:
        """What tick k waits for (lockstep, in /diagnostics), None when nothing."""
        return None


class LockstepPlant(PlantClock):
    """Publish tick k (measurement, /clock), wait until every answer of it is in, integrate,
    publish tick k+1; re-send an unanswered tick; never more than ``record_window`` ticks
    ahead of the harness's recorder; tick k at wall ``start + t_k / rtf`` when rtf > 0."""

    mode = 'lockstep'
    ticks = True
    prestart_reports = False

    def __init__(self, host: PlantHost, plant: Any, noise: Any, values: Mapping[str, Any],
                 counters: dict[str, int], future: FutureStamps, session: str) -> None:
        super().__init__(host, plant, noise, values, counters, future, session)
        required: dict[str, tuple[str, ...]] = {MANIPULATED: plant.input_names}
        if values['lockstep.wait_for_reference']:
            required[DISTURBANCE] = ()
        # the reference's disturbance is a zero-order-hold stream in lockstep (nodes/clock.Held)
        self.inbox = StampedInbox(required, held=(DISTURBANCE,))
        # flow control with the harness's recorder, off the tick's serial path: tick k is
        # published only while k <= (last tick the recorder holds whole) + record_window
        self.window = int(values['lockstep.record_window'])
        self.recorded_tick = -1            # the recorder's last acknowledged tick
        self.held_for_recorder = False     # tick k waits for an acknowledgment
        self._resend_timer = host.timer(min(self.resend_period / 2, 0.05), self.on_resend)
        self._wall_start = time.monotonic()
        self._pace_timer: Timer | None = None
        self.set_rtf(float(values['real_time_factor']))

    def send(self) -> None:
        assert self.tick_msgs is not None
        msg, clock = self.tick_msgs
        assert clock is not None
        # /clock first: it starts the longest answer chain (reference → setpoint →
        # controller), the measurement only has to be there when the setpoint is.
        self.host.publish_clock(clock)
        self.host.publish_measurement(msg)
        self.sent_at = time.monotonic()

    def _take(self, topic: str, t_ns: int, names: tuple[str, ...], accepted: dict[str, float],
              known: tuple[str, ...]) -> None:
        current = self.k * self.ts_ns
        # a disturbance stamped before the tick is a re-sent one still in force (Held)
        low = current if topic == MANIPULATED else -1
        if not low <= t_ns <= current + _LOOKAHEAD * self.ts_ns:
            return                      # a stale duplicate, or far ahead
        held = self.u if topic == MANIPULATED else self.d
        # A known channel with an ignored (non-finite) value still answers the
        # tick: its last valid value is kept.
        answered = {n: accepted.get(n, held[n]) for n in names if n in known}
        # Answers for a later tick (the reference publishes ahead) wait in the inbox.
        self.inbox.put(topic, t_ns, answered)
        if self.awaiting and self.inbox.complete(current):
            self._advance(current)

    def _advance(self, t_ns: int) -> None:
        manipulated = self.inbox.values(t_ns, MANIPULATED)
        self.note_applied(manipulated)
        self.u.update(manipulated)
        self.d.update(self.inbox.values(t_ns, DISTURBANCE))
        self.awaiting = False
        self.step()
        self.inbox.drop_before(self.k * self.ts_ns)
        if self.host.paused:
            self.publish_applied(self.k - 1)
            return                      # un-pausing publishes the next tick
        self._next_tick()

    def _recorder_allows(self, tick: int) -> bool:
        """``lockstep.record_window``: tick may be published. Tick 1 waits until the recorder
        holds tick 0 whole — its receipt shows that every signal writer has matched the
        recorder's readers (a volatile writer sends nothing to a reader it has not matched
        yet) — later ticks run up to ``record_window`` ahead."""
        recorded = self.recorded_tick
        return not self.window or tick <= recorded + (self.window if recorded >= 0 else 1)

    def _next_tick(self) -> None:
        """Publish tick k now, at its wall time (pacing), or once the recorder has
        acknowledged enough (``_recorder_allows``)."""
        if not self._recorder_allows(self.k):
            self.held_for_recorder = True      # recorded() publishes it
            return
        self.held_for_recorder = False
        if self._pace_timer is None or self._wait_ns() <= 0:
            self.publish_tick()
        else:                           # a one-shot at the tick's wall time
            self._pace_timer.timer_period_ns = self._wait_ns()
            self._pace_timer.reset()

    def recorded(self, stamp_ns: int) -> None:
        """The recorder holds every tick up to this stamp (``lockstep.record_window``).

        Why nothing is lost: the plant publishes a new tick only within ``record_window``
        (<= 8) ticks of the last one the recorder holds, and re-sends its last tick only
        when the recorder holds every earlier one; each answer is published once per
        (re-)sent tick. Once the recorder held tick 0 whole every writer had matched its
        readers, so from then on, between the first message of a tick the recorder has not
        taken and now, each signal publisher wrote fewer messages than it keeps (or only
        copies of that same tick): plant and controller at most 8 + 1 of their keep-last 10,
        the reference, ``lockstep.lookahead`` (<= 8) ticks further ahead, at most 17 of its
        32 (``messages.REFERENCE_QOS``). The reliable writer still holds the message for the
        recorder's keep-all reader, whatever the scheduler does to the harness process."""
        tick = (stamp_ns - self.stamp_offset_ns) // self.ts_ns
        if tick <= self.recorded_tick:
            return
        self.recorded_tick = tick
        if (self.held_for_recorder and not self.awaiting and not self.host.paused
                and self.tick_msgs is not None):
            self._next_tick()

    def set_rtf(self, rtf: float) -> None:
        """rtf 0: next tick at once; rtf > 0: tick k at wall ``start + t_k / rtf``
        (a one-shot timer armed for each tick that is early, no polling)."""
        if self._pace_timer is not None:
            self.host.destroy(self._pace_timer)
            self._pace_timer = None
        self._rtf = rtf
        if rtf > 0:
            self._wall_start = time.monotonic() - self.t() / rtf
            self._pace_timer = self.host.timer(self.ts / rtf, self._on_pace, autostart=False)

    def _wait_ns(self) -> int:
        """Wall nanoseconds until tick k is due (<= 0: due)."""
        return int((self._wall_start + self.t() / self._rtf - time.monotonic()) * 1e9)

    def _on_pace(self) -> None:
        assert self._pace_timer is not None
        self._pace_timer.cancel()
        if self.awaiting or self.tick_msgs is None or self.host.paused:
            return
        wait = self._wait_ns()
        if wait <= 0:
            self.publish_tick()
        else:                           # woke a little early: sleep the rest on the timer
            self._pace_timer.timer_period_ns = wait
            self._pace_timer.reset()

    def on_resend(self) -> None:
        """Re-send the last tick published if unanswered, or not yet held whole by the recorder
        (``record_window``: tick k−1 while k waits for it, e.g. tick 0 whose answers came before
        the recorder had matched their writers), for ``lockstep.resend_period`` — with
        ``record_window``, only once the recorder holds every tick before it (see
        ``recorded``)."""
        if self.host.paused:            # paused: nothing is published, re-sends neither
            return
        last = self.k if self.awaiting else self.k - 1
        if self.window and self.recorded_tick < last - 1:
            return
        if ((self.awaiting or self.held_for_recorder) and self.tick_msgs is not None
                and time.monotonic() - self.sent_at >= self.resend_period):
            self.publish_applied(self.k - 1)
            self.counters['resent_ticks'] += 1
            self.send()

    def set_paused(self, paused: bool, was_paused: bool, unpaused: bool) -> None:
        if paused and not was_paused:
            self.publish_applied(self.k - 1)     # what a controller started now takes over
        if unpaused and not self.awaiting:
            if self._pace_timer is not None:
                self._wall_start = time.monotonic() - self.t() / self._rtf
            self._next_tick()

    def stall_report(self) -> str:
        """Tick k unanswered for ``STALL_RESENDS`` re-send periods (a node is down, or
        restarting): ``stalled <s> s at t = <t> s: waiting for manipulated.u (controller)``."""
        if self.host.paused:
            return ''
        waited = time.monotonic() - self.tick_published_at
        if not self.awaiting or waited < STALL_RESENDS * self.resend_period:
            return ''
        current = self.k * self.ts_ns
        missing = self.inbox.missing(current)
        # The reference publishes ahead (Held): once it has answered /clock t_k its
        # streams reach t_k+1. One that has not is behind, and the controller may wait
        # for its setpoint though the plant holds the disturbance of this tick.
        behind = self.inbox.held[DISTURBANCE].through < current + (self.ts_ns if self.k else 0)
        # A live reference answers every re-sent /clock with its messages in force again;
        # one silent since the first re-send is down, though the controller may be what
        # the tick waits for (it lacks the setpoint the dead reference's last message,
        # delivered to the plant, never brought it).
        heard = self.arrivals.get(DISTURBANCE, (-math.inf, 0.0))[0]
        silent = heard < self.tick_published_at + self.resend_period
        if (DISTURBANCE in self.inbox.required and (behind or silent)
                and DISTURBANCE not in missing):
            missing.append(DISTURBANCE)
        named = ', '.join(f'{m} ({_ANSWERED_BY.get(m.split(".")[0], "?")})' for m in missing)
        return f'stalled {waited:.3g} s at t = {self.t():g} s: waiting for {named}'

    def waiting_for(self) -> str | None:
        if not self.awaiting:
            return None
        return ', '.join(self.inbox.missing(self.k * self.ts_ns))


class _Timed(PlantClock):
    """sim and wall: step on a timer with the latest inputs held; an answer that came after
    its tick was integrated is reported (``~/late_inputs``)."""

    def __init__(self, host: PlantHost, plant: Any, noise: Any, values: Mapping[str, Any],
                 counters: dict[str, int], future: FutureStamps, session: str) -> None:
        super().__init__(host, plant, noise, values, counters, future, session)
        # stamp of the input message held per topic, and the inputs each recent tick was
        # integrated with (for ~/late_inputs)
        self.held_stamp: dict[str, int] = {}
        self.integrated: dict[int, dict[str, float]] = {}

    def _before_step(self) -> None:
        self.integrated[self.k * self.ts_ns] = {**self.u, **self.d}   # for ~/late_inputs
        self.integrated.pop((self.k - _LATE_MEMORY) * self.ts_ns, None)
        self.publish_applied(self.k)    # lockstep: only when the loop stops (on_resend)

    def _take(self, topic: str, t_ns: int, names: tuple[str, ...], accepted: dict[str, float],
              known: tuple[str, ...]) -> None:
        """Hold the newest values; report an answer that came after its tick was integrated
        (``~/late_inputs``, docs/nodes.md "Late answers"); one older than the values held
        (out of order, unstamped) is refused (``rejected_past``)."""
        if t_ns < self.held_stamp.get(topic, t_ns):
            if not self.future.back_on_clock(topic, self.held_stamp[topic], t_ns,
                                             self.now_ns()):
                self._refuse_past(topic, t_ns)
                return                  # older than the values held: out of order
            self._clear_ahead(topic)    # the stepped values waiting for their stamps
            for text in self.future.take_report():
                self.host.warning(text)
        if self.tick_msgs is not None and t_ns - self.stamp_offset_ns < self.k * self.ts_ns:
            self.counters['late_inputs'] += 1
            tick = (t_ns - self.stamp_offset_ns) // self.ts_ns * self.ts_ns
            used = self.integrated.get(tick, {})
            self.host.publish_late(t_ns, list(accepted),
                                   [used.get(n, math.nan) for n in accepted])
        self.held_stamp[topic] = t_ns
        self._hold(topic, t_ns, accepted)

    def _refuse_past(self, topic: str, t_ns: int) -> None:
        """Count (``rejected_past``) and log, at most once per diagnostics period per topic
        (``past_logged``), an input stamped before the values held: they stay."""
        count = self.counters['rejected_past'] = self.counters.get('rejected_past', 0) + 1
        if topic not in self.past_logged:
            self.past_logged.add(topic)
            what = 'unstamped (stamp 0)' if t_ns == 0 else f'stamped {t_ns / 1e9:.13g} s'
            fix = PAST_FIX_WALL if self.real_time else PAST_FIX_SIM
            self.host.warning(f'{topic}: message {what} refused, older than the '
                              f'{self.held_stamp[topic] / 1e9:.13g} s held: the values held '
                              f'stay ({count} so far); {fix} (logged at most once per '
                              'diagnostics period)')

    def _clear_ahead(self, topic: str) -> None:
        pass

    def _hold(self, topic: str, t_ns: int, accepted: dict[str, float]) -> None:
        (self.u if topic == MANIPULATED else self.d).update(accepted)
        if topic == MANIPULATED:
            self.note_applied(accepted)

    def set_paused(self, paused: bool, was_paused: bool, unpaused: bool) -> None:
        """Stop the tick timer; publish tick 0 (first start) and restart the timer so that
        the next tick comes one full period later."""
        if paused == was_paused:
            return
        if paused:
            self.timer.cancel()
            return
        self.start_clock()

    def start_clock(self) -> None:
        if self.tick_msgs is None and self.host.match_wait():
            return                        # tick 0 once every reader and writer is matched
        if self.tick_msgs is None:
            self.publish_tick()
        self.timer.reset()

    def stall_report(self) -> str:
        """``manipulated`` silent for ``STALL_INTERVALS`` of its recent intervals (at least
        ``STALL_MIN_S``) after it had come: ``no manipulated (controller) for <s> s: inputs
        held``; or what has sent nothing since the first tick (``_never_received``)."""
        now = time.monotonic()
        if self.host.paused:
            return ''
        never = self._never_received(now)
        if never:
            return never
        arrival = self.arrivals.get(MANIPULATED)
        if arrival is None:
            return ''
        silent = now - arrival[0]
        if silent < max(STALL_MIN_S, STALL_INTERVALS * arrival[1]):
            return ''
        return (f'no {MANIPULATED} ({_ANSWERED_BY[MANIPULATED]}) for {silent:.3g} s: '
                'inputs held')

    def _never_received(self, now: float) -> str:
        """'' or which input topics have sent nothing ``NEVER_RECEIVED_S`` after the first
        tick: ``waiting for manipulated (controller), disturbance (reference): nothing
        received in <s> s; inputs held at their initial values``."""
        if self.first_tick_at is None or now - self.first_tick_at < NEVER_RECEIVED_S:
            return ''
        topics = [MANIPULATED] if self.plant.input_names else []
        if self.plant.disturbance_names:
            topics.append(DISTURBANCE)
        missing = [t for t in topics if t not in self.arrivals]
        if not missing:
            return ''
        named = ', '.join(f'{t} ({_ANSWERED_BY[t]})' for t in missing)
        return (f'waiting for {named}: nothing received in {now - self.first_tick_at:.3g} s; '
                'inputs held at their initial values')

    timer: Timer


class SimPlant(_Timed):
    """sim: a tick every ``sample_time / real_time_factor`` of wall time, /clock with it."""

    mode = 'sim'

    def __init__(self, host: PlantHost, plant: Any, noise: Any, values: Mapping[str, Any],
                 counters: dict[str, int], future: FutureStamps, session: str) -> None:
        super().__init__(host, plant, noise, values, counters, future, session)
        self.timer = host.timer(self.ts / float(values['real_time_factor']), self.on_timer,
                                autostart=not host.paused)

    def _pace_target(self) -> float | None:
        return self.host.real_time_factor

    def set_rtf(self, rtf: float) -> None:
        if rtf > 0:
            self.timer.timer_period_ns = to_ns(self.ts / rtf)

    def on_timer(self) -> None:
        """Close the previous interval with the latest inputs, publish tick k."""
        if self.host.paused:
            return                      # a call that was due when the pause came
        if self.tick_msgs is None:
            return
        self.step()
        self.publish_tick()


class WallPlant(_Timed):
    """wall: ticks on the wall clock's grid from a time origin announced ahead; disturbance
    values stamped ahead (the reference's ``wall.lead``) wait for their step."""

    mode = 'wall'
    real_time = True
    publishes_clock = False

    def __init__(self, host: PlantHost, plant: Any, noise: Any, values: Mapping[str, Any],
                 counters: dict[str, int], future: FutureStamps, session: str) -> None:
        super().__init__(host, plant, noise, values, counters, future, session)
        self._wall_t0_ns = 0               # steady time of tick 0 [ns]
        self._d_ahead = Scheduled()        # disturbance values ahead of their instant
        self.timer = host.timer(self.ts, self.on_timer, autostart=False)

    def _pace_target(self) -> float | None:
        return 1.0

    def start(self) -> None:
        if not self.host.paused:
            self.start_clock()            # the time origin: tick 0 ORIGIN_NOTICE_S from now

    def pause_refused(self, paused: bool) -> str | None:
        if paused and self.announced:
            return ('lockstep.paused: true refused, a running wall clock cannot be paused '
                    '(only held before its time origin is announced); allowed false')
        return None

    def now_ns(self) -> int | None:
        """The time on its own grid (origin + steady time since tick 0), None before the
        origin is announced."""
        if not self.announced:
            return None
        return self.stamp_offset_ns + time.monotonic_ns() - self._wall_t0_ns

    def _clear_ahead(self, topic: str) -> None:
        if topic == DISTURBANCE:
            self._d_ahead.clear()

    def _hold(self, topic: str, t_ns: int, accepted: dict[str, float]) -> None:
        if topic == DISTURBANCE:
            # the reference publishes each instant ``wall.lead`` ahead: held until the step
            # that starts at its stamp (_before_step)
            self._d_ahead.put(t_ns - self.stamp_offset_ns, accepted)
            return
        super()._hold(topic, t_ns, accepted)

    def _before_step(self) -> None:
        self._d_ahead.release(self.k * self.ts_ns, self.d)   # stamped at or before t_k
        super()._before_step()

    def start_clock(self) -> None:
        if self.tick_msgs is None and self.host.match_wait():
            return                        # tick 0 once every reader and writer is matched
        if self.tick_msgs is not None:
            self.timer.reset()
            return
        if self.announced:
            return                        # tick 0 is on its way
        # tick 0, the origin of plant time, is announced ORIGIN_NOTICE_S (whole periods)
        # ahead: the reference publishes instant 0 and the controller has it before
        # measurement 0 (announced at tick 0, the origin raced the measurement: instant 0
        # came after it or, a reference that heard the origin more than wall.lead late,
        # never). The timer's grid (steady clock, as time.monotonic_ns) starts now, the
        # origin on it: armed later, every call would come that much after its instant.
        notice_ns = -(-to_ns(ORIGIN_NOTICE_S) // self.ts_ns) * self.ts_ns
        self._wall_t0_ns = time.monotonic_ns() + notice_ns
        self.stamp_offset_ns = self.host.ros_now_ns() + notice_ns
        self.timer.reset()
        self.host.publish_origin(self.stamp_offset_ns)
        self.announced = True

    def on_timer(self) -> None:
        """Publish tick 0 at the announced origin; then close the previous interval with the
        latest inputs and publish tick k.

        The measurement is that of the latest grid instant that has come,
        ``k = floor((now - t0) / ts)``, stamped ``origin + k·ts`` (its sample instant), never
        one ahead of it. A call that finds more than one period elapsed (a busy process, a
        late executor) integrates the periods in between with the inputs held, one step each,
        and does not publish them: they are counted as ``missed_samples`` (each tick is either
        published or counted, once). The executor may also call early (rclpy's EventsExecutor
        runs a timer that fell more than a period behind twice at once, the second call up
        to a period ahead of its instant). Integration stops after one period of work (a
        plant slower than real time), so parameter services and diagnostics still run; the
        tick reached is then published, stamped with its own (past) instant."""
        if self.host.paused:
            return                      # a call that was due when the pause came
        if self.tick_msgs is None:      # tick 0 announced (start_clock), not yet come
            if self._wait_for(self._wall_t0_ns):
                self.publish_tick()
            return
        if not self._wait_for(self._wall_t0_ns + (self.k + 1) * self.ts_ns):
            return
        now_ns = time.monotonic_ns()
        due = max((now_ns - self._wall_t0_ns) // self.ts_ns, self.k + 1)
        steps = 0
        while self.k < due:
            self.step()
            steps += 1
            if time.monotonic_ns() - now_ns > self.ts_ns:
                break                   # behind real time: the rest at the next call
        self.counters['missed_samples'] += steps - 1   # integrated, never published
        self.publish_tick()

    def _wait_for(self, instant_ns: int) -> bool:
        """Is the timer's call for the steady-clock ``instant_ns``? A call more than half a
        period early is not (a made-up call, or one of the countdown to tick 0); one a little
        early waits for the instant."""
        ahead_ns = instant_ns - time.monotonic_ns()
        if ahead_ns > self.ts_ns // 2:
            return False
        if ahead_ns > 0:
            time.sleep(ahead_ns / 1e9)
        return True


_PLANTS: dict[str, type[PlantClock]] = {'lockstep': LockstepPlant, 'sim': SimPlant,
                                        'wall': WallPlant}


def plant_clock(mode: str) -> type[PlantClock]:
    """The protocol class of clock ``mode`` (wall, sim, lockstep)."""
    return _PLANTS[mode]
