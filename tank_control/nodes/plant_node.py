"""plant_node: simulates a core plant kind (parameter ``plant``) and is the clock master.

Publishes ``measurement`` (outputs plus seeded noise), ``/clock`` (sim, lockstep),
``time_origin``, ``applied_input`` (latched: what a restarted controller takes over from),
``~/late_inputs``, ``/diagnostics`` (WARN on a stalled loop, naming what it waits for);
subscribes ``manipulated`` and ``disturbance`` by channel name. Clock modes ``wall``/``sim``/``lockstep``, the lockstep
protocol and ``lockstep.paused``: docs/nodes.md. Units: those of the plant kind; times in s.
"""
from __future__ import annotations

import math
import sys
import time
import uuid
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tank_control.core import node_specs, params_file, ranges
from tank_control.core.interfaces import seconds, to_ns
from tank_control.core.loop import nominal_disturbances, nominal_inputs
from tank_control.core.node_specs import PlantNode as PlantNodeConfig
from tank_control.core.params import ConfigError, names_of
from tank_control.core.plants.noise import NoiseConfig
from tank_control.core.scenario import plant_setup
from tank_control.core.stamps import FutureStamps, future_tolerance_ns
from tank_control.nodes.clock import Scheduled, StampedInbox, steady_clock
from tank_control.nodes.messages import (APPLIED_QOS, CLOCK_QOS, LATE_QOS, ORIGIN_QOS,
                                         RECORDED_QOS, SIGNAL_QOS, TOPIC_APPLIED_INPUT,
                                         TOPIC_CLOCK, TOPIC_RECORDED,
                                         TOPIC_DIAGNOSTICS, TOPIC_DISTURBANCE,
                                         TOPIC_LATE_INPUTS, TOPIC_MANIPULATED, TOPIC_MEASUREMENT,
                                         TOPIC_TIME_ORIGIN, ChannelFilter, ns_to_stamp,
                                         stamp_to_ns,
                                         quiet_publisher_events, quiet_subscription_events,
                                         to_joint_state, unmatched, MATCH_WAIT_S)
from tank_control.nodes.cdr import JointStateCdr, clock_cdr_ns
from tank_control.nodes.params import ParameterBinding, ParameterError
from tank_control.nodes.runtime import main as run_node_main

_NODE_ONLY = frozenset(names_of(PlantNodeConfig)) | frozenset(names_of(NoiseConfig))
_NODE_ONLY_PREFIX = ranges.PREFIX      # range.*: the filters', not the model's
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
#: who answers each input topic (named in the stall report)
_ANSWERED_BY = {TOPIC_MANIPULATED: 'controller', TOPIC_DISTURBANCE: 'reference'}


def _controller_values(name: str, argv: list[str] | None = None) -> dict[str, Any] | None:
    """The parameter values the controller ``name`` gets from the ``--params-file`` files on
    this node's command line (None if none has a section for it, or one cannot be read)."""
    values: dict[str, Any] = {}
    found = False
    for path in params_file.ros_params_files(sys.argv if argv is None else argv):
        try:
            sections = params_file.read(path)
        except ConfigError:
            return None               # rcl reports an unreadable file itself
        own = params_file.values_for(sections, name)
        if own is not None and params_file.values_for(sections, name, use_wildcards=False):
            found = True
        values.update(own or {})
    return values if found else None


class PlantNode(Node):
    """The plant simulation node, clock master of the run (docs/nodes.md)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('plant', allow_undeclared_parameters=True, **kwargs)
        # The model kind decides which parameters exist.
        override = getattr(self, '_parameter_overrides', {}).get('plant')
        try:
            kind = node_specs.kind_of('plant', {} if override is None else {'plant': override.value})
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        # the controller's parameters in the same --params-file (a scenario, the harness's
        # file): its output limits are the inputs' default range.* (core/ranges.py)
        self._controller_values = _controller_values(
            f'{self.get_namespace().rstrip("/")}/controller')
        self._actuator = node_specs.actuator_defaults(self._controller_values)
        self.params = ParameterBinding(
            self, node_specs.plant_specs(kind, self._controller_values),
            cross_check=self._cross_check)
        values = self.params.values
        try:
            setup = plant_setup(values, self._controller_values)
            self.plant = setup.build_plant()
            self.noise = setup.build_noise(len(self.plant.output_names))
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None
        self.mode = str(values['clock_mode'])
        self.ts = float(values['sample_time'])
        self.ts_ns = to_ns(self.ts)
        self.k = 0
        self.u = nominal_inputs(self.plant)
        self.d = nominal_disturbances(self.plant)
        self._wall_t0_ns = 0               # wall: steady time of tick 0 [ns]
        self.counters = {'ticks': 0, 'missed_samples': 0, 'resent_ticks': 0, 'ignored_inputs': 0,
                         'late_inputs': 0, 'rejected_changes': 0, 'out_of_range_inputs': 0,
                         'rejected_future': 0, 'unknown_channels': 0, 'oversized_inputs': 0}
        # inputs stamped more than max_future_stamp ahead of this plant's now are refused
        # (core/stamps.py): one would hold every later input as "older" (docs/nodes.md)
        self._future = FutureStamps(future_tolerance_ns(
            values['max_future_stamp'], self.ts, self.mode == 'lockstep'))

        self.measurement_pub = self.create_publisher(JointState, TOPIC_MEASUREMENT, SIGNAL_QOS,
                                                     event_callbacks=quiet_publisher_events())
        self.clock_pub = (self.create_publisher(Clock, TOPIC_CLOCK, CLOCK_QOS,
                                                event_callbacks=quiet_publisher_events())
                          if self.mode in ('sim', 'lockstep') else None)
        self.diag_pub = self.create_publisher(DiagnosticArray, TOPIC_DIAGNOSTICS, 10,
                                               event_callbacks=quiet_publisher_events())
        self.origin_pub = self.create_publisher(Time, TOPIC_TIME_ORIGIN, ORIGIN_QOS)
        self.late_pub = self.create_publisher(JointState, TOPIC_LATE_INPUTS, LATE_QOS)
        # the manipulated values applied, latched: channels a controller sent (none yet: an
        # empty message, so a controller that starts now knows it starts a new loop)
        self.applied_pub = self.create_publisher(JointState, TOPIC_APPLIED_INPUT, APPLIED_QOS)
        # this plant process's session: header.frame_id of its measurements and applied inputs,
        # so a controller takes over from this plant's values, never a dead one's
        self._session = uuid.uuid4().hex[:16]
        self._applied_names: list[str] = []
        self._applied_sent: tuple[float, ...] | None = None
        # hot-path messages as pre-encoded CDR (nodes/cdr.py): measurement, applied_input
        self._measurement_cdr = JointStateCdr(self.plant.output_names, self._session)
        self._applied_cdr = JointStateCdr((), self._session)
        self.applied_pub.publish(self._applied_cdr.encode_ns(0, ()))
        # stall watch: wall time tick k was first published (lockstep); per input topic the
        # last arrival and the interval before it (wall/sim) [s, time.monotonic]
        self._tick_published_at = time.monotonic()
        self._first_tick_at: float | None = None
        self._arrivals: dict[str, tuple[float, float]] = {}
        self._stall_logged = ''          # the stall last logged ('' = none: the loop moves)
        # sim/wall: stamp of the input message held per topic, and the inputs each recent
        # tick was integrated with (for ~/late_inputs)
        self._held_stamp: dict[str, int] = {}
        self._d_ahead = Scheduled()          # wall: disturbance values ahead of their instant
        self._integrated: dict[int, dict[str, float]] = {}
        # a value outside its range.* is ignored like a non-finite one (last valid kept)
        self.filters = {TOPIC_MANIPULATED: ChannelFilter(self.plant.input_names,
                                                         ranges=setup.ranges),
                        TOPIC_DISTURBANCE: ChannelFilter(self.plant.disturbance_names,
                                                         ranges=setup.ranges)}
        # taken as CDR bytes and decoded directly (nodes/cdr.py)
        self._input_subs = [
            self.create_subscription(JointState, topic, lambda m, t=topic: self._on_input(t, m),
                                     SIGNAL_QOS, event_callbacks=quiet_subscription_events(),
                                     raw=True)
            for topic in (TOPIC_MANIPULATED, TOPIC_DISTURBANCE)]
        self._match_since: float | None = None     # sim/wall: the wait before tick 0 (_match_wait)
        self._announced = False            # wall: the time origin is published (_start_timer)
        self._match_timer = None

        required: dict[str, tuple[str, ...]] = {TOPIC_MANIPULATED: self.plant.input_names}
        if values['lockstep.wait_for_reference']:
            required[TOPIC_DISTURBANCE] = ()
        # the reference's disturbance is a zero-order-hold stream in lockstep (nodes/clock.Held)
        self.inbox = StampedInbox(required, held=(TOPIC_DISTURBANCE,))
        # lockstep flow control with the harness's recorder, off the tick's serial path: tick k
        # is published only while k <= (last tick the recorder holds whole) + record_window
        self._window = int(values['lockstep.record_window']) if self.mode == 'lockstep' else 0
        self._recorded_tick = -1           # the recorder's last acknowledged tick
        self._held_for_recorder = False    # tick k waits for an acknowledgment
        if self._window:
            self.create_subscription(Time, TOPIC_RECORDED, self._on_recorded, RECORDED_QOS,
                                     event_callbacks=quiet_subscription_events())
        self._tick_msgs: tuple[bytes, bytes | None] | None = None   # CDR: measurement, /clock
        self._awaiting = False
        self._sent_at = 0.0
        self._wall_start = time.monotonic()
        self._stamp_offset_ns = 0          # the time origin (wall: set at tick 0)
        steady = steady_clock()
        rtf = float(values['real_time_factor'])
        self._is_paused = bool(values['lockstep.paused'])
        if self.mode == 'wall':
            self._timer = self.create_timer(self.ts, self._on_tick_timer, clock=steady,
                                            autostart=False)
        elif self.mode == 'sim':
            self._timer = self.create_timer(self.ts / rtf, self._on_tick_timer, clock=steady,
                                            autostart=not self._is_paused)
        else:
            period = float(values['lockstep.resend_period'])
            self._resend_timer = self.create_timer(min(period / 2, 0.05), self._on_resend,
                                                   clock=steady)
            self._pace_timer = None
            self._set_pacing(rtf)
        self.create_timer(float(values['diagnostics_period']), self._publish_diagnostics,
                          clock=steady)
        self._matched_sent: dict[str, int] | None = None   # in the last /diagnostics
        self._prestart_calls = 0           # sim/wall (the harness waits for them): _on_prestart
        self._prestart_timer = (self.create_timer(0.02, self._on_prestart, clock=steady)
                                if self.mode != 'lockstep' else None)
        self._pace_mark: tuple[float, int] | None = None   # (wall s, tick) at the last report
        self._step_s = 0.0                 # computation time of plant.step since the report
        self._steps = 0
        self._step_ms = 0.0                # its mean over the last report's period [ms]
        self._resend_period = float(values['lockstep.resend_period'])
        self.add_post_set_parameters_callback(self._on_params_set)
        if self.mode != 'wall':
            self.origin_pub.publish(ns_to_stamp(0))   # the simulated clock starts at 0
        if not self._paused() and self.mode == 'wall':
            self._start_timer()           # the time origin: tick 0 ORIGIN_NOTICE_S from now
        elif not self._paused():
            self._publish_tick()          # tick 0 right away (lockstep: re-sent until answered)
        self.get_logger().info(
            f'plant {kind} ({setup.kind.description}): outputs {list(self.plant.output_names)}, inputs '
            f'{list(self.plant.input_names)}, disturbances {list(self.plant.disturbance_names)}; '
            f'{self.mode} clock, sample_time {self.ts:g} s')

    # ------------------------------------------------------------- parameters
    def _cross_check(self, values: dict[str, Any], changed: frozenset[str]) -> str | None:
        """The whole candidate set as at start-up (node relations, the model's configuration
        and its relations such as dead_time <= max_dead_time) and noise_std: 1 value or one
        per output."""
        if (values['clock_mode'] == 'wall' and values['lockstep.paused']
                and getattr(self, '_announced', False)):
            return ('lockstep.paused: true refused, a running wall clock cannot be paused '
                    '(only held before its time origin is announced); allowed false')
        try:
            setup = plant_setup(values, getattr(self, '_controller_values', None))
            if hasattr(self, 'plant'):   # at start-up the constructor builds the noise next
                setup.build_noise(len(self.plant.output_names))
        except ConfigError as exc:
            return str(exc)
        return None

    def _apply_pending(self) -> None:
        """Accepted parameter changes act from this step on."""
        pending = self.params.take_pending()
        if not pending:
            return
        model = {k: v for k, v in pending.items()
                 if k not in _NODE_ONLY and not k.startswith(_NODE_ONLY_PREFIX)}
        if model:
            try:
                self.plant.configure(**model)
                self.get_logger().info(f'model change applied at t = {self._t():g} s: {model}')
            except ValueError as exc:   # a relation the model checks (e.g. dead_time <= max)
                self.counters['rejected_changes'] += 1
                self.get_logger().warning(f'model change not applied: {exc}')
        if 'noise_std' in pending:
            self.noise.set_std(pending['noise_std'])
        if 'real_time_factor' in pending and self.mode == 'lockstep':
            self._set_pacing(float(pending['real_time_factor']))
        elif 'real_time_factor' in pending and self.mode == 'sim':
            rtf = float(pending['real_time_factor'])
            if rtf > 0:
                self._timer.timer_period_ns = to_ns(self.ts / rtf)

    def _paused(self) -> bool:
        return self._is_paused

    def _on_params_set(self, parameters: list) -> None:
        """(Un-)pausing acts at once (other changes wait for the next step)."""
        # rclpy may run this before the binding's own post-set callback: read the new value.
        was_paused = self._is_paused
        given = {p.name: p.value for p in parameters if p.name.startswith(ranges.PREFIX)}
        if given:                         # range.* act on the next message
            limits = ranges.ranges_from({**self.params.values, **given},
                                        node_specs.plant_channels(self.params.values['plant']),
                                        self._actuator)
            for flt in self.filters.values():
                flt.ranges = limits
        for p in parameters:
            if p.name == 'lockstep.paused':
                self._is_paused = bool(p.value)
            elif p.name == 'lockstep.resend_period':
                self._resend_period = float(p.value)
        if self.mode in ('sim', 'wall') and self._is_paused != was_paused:
            self._pause_timer(self._is_paused)
            return
        if self.mode == 'lockstep' and self._is_paused and not was_paused:
            self._publish_applied(self.k - 1)     # what a controller started now takes over
        unpaused = any(p.name == 'lockstep.paused' and not p.value for p in parameters)
        if self.mode == 'lockstep' and unpaused and not self._awaiting:
            if self._pace_timer is not None:
                self._wall_start = time.monotonic() - self._t() / self._rtf
            self._next_tick()

    def _pause_timer(self, paused: bool) -> None:
        """sim: stop the tick timer; sim/wall: publish tick 0 (first start) and restart the
        timer so that the next tick comes one full period later."""
        if paused:
            self._timer.cancel()
            return
        self._start_timer()

    def _start_timer(self) -> None:
        if self._tick_msgs is None and self._match_wait():
            return                        # tick 0 once every reader and writer is matched
        if self._tick_msgs is None and self.mode == 'wall':
            if self._announced:
                return                    # tick 0 is on its way
            # tick 0, the origin of plant time, is announced ORIGIN_NOTICE_S (whole periods)
            # ahead: the reference publishes instant 0 and the controller has it before
            # measurement 0 (announced at tick 0, the origin raced the measurement: instant 0
            # came after it or, a reference that heard the origin more than wall.lead late,
            # never). The timer's grid (steady clock, as time.monotonic_ns) starts now, the
            # origin on it: armed later, every call would come that much after its instant.
            notice_ns = -(-to_ns(ORIGIN_NOTICE_S) // self.ts_ns) * self.ts_ns
            self._wall_t0_ns = time.monotonic_ns() + notice_ns
            self._stamp_offset_ns = self.get_clock().now().nanoseconds + notice_ns
            self._timer.reset()
            self.origin_pub.publish(ns_to_stamp(self._stamp_offset_ns))
            self._announced = True
            return
        if self._tick_msgs is None:
            self._publish_tick()
        self._timer.reset()

    def _match_wait(self) -> bool:
        """sim/wall, before tick 0: are readers of the measurement, the time origin, the
        applied input (a controller's take-over waits for it) or /clock, or writers of the
        inputs, in the graph but not yet matched (``messages.unmatched``)?
        Then tick 0 waits (polled every 10 ms) — a tick or origin published before would
        reach them late or never, and the plant does not wait for answers — for at most
        MATCH_WAIT_S, then starts with a warning naming the topics."""
        waiting = unmatched(self, self._start_publishers(), self._input_subs)
        now = time.monotonic()
        if self._match_since is None:
            self._match_since = now
        if waiting and now - self._match_since < MATCH_WAIT_S:
            if self._match_timer is None:
                self._match_timer = self.create_timer(0.01, self._retry_start,
                                                      clock=steady_clock())
            return True
        if waiting:
            self.get_logger().warning(
                f'starting the clock after {MATCH_WAIT_S:g} s with {", ".join(waiting)} not '
                'matched to every endpoint the graph shows (incompatible QoS?): their messages '
                'may come late or not at all')
        if self._match_timer is not None:
            self._match_timer.cancel()         # (maybe in its own callback: not destroyed)
        return False

    def _start_publishers(self) -> list[Any]:
        """Publishers whose readers must be matched before tick 0 (``_match_wait``)."""
        return [p for p in (self.measurement_pub, self.origin_pub, self.applied_pub,
                            self.clock_pub) if p is not None]

    def _matched(self) -> dict[str, int]:
        """``matched_readers.<topic>``: readers the middleware has matched to the writer of
        each ``_start_publishers`` topic; ``matched_writers.<topic>``: writers matched to each
        input. In /diagnostics: the harness starts the clock once these reach the endpoints
        its own graph shows (the plant's graph can miss a node for seconds)."""
        items = {f'matched_readers.{p.topic_name}': p.get_subscription_count()
                 for p in self._start_publishers()}
        items.update({f'matched_writers.{s.topic_name}': s.get_publisher_count()
                      for s in self._input_subs})
        return items

    def _on_prestart(self) -> None:
        """Before tick 0 (every 20 ms): /diagnostics at once when a matched count changed,
        else every 0.1 s (a reader that joined after the change need not wait for the
        ``diagnostics_period``)."""
        if self._tick_msgs is not None or self._announced:
            self._prestart_timer.cancel()      # (cancelled, not destroyed, in its own callback)
            return
        self._prestart_calls += 1
        if self._matched() != self._matched_sent or self._prestart_calls % 5 == 0:
            self._publish_diagnostics()

    def _retry_start(self) -> None:
        if self._tick_msgs is None and not self._paused():
            self._start_timer()

    # ----------------------------------------------------------------- ticks
    def _t(self) -> float:
        return seconds(self.k * self.ts_ns)

    def _publish_tick(self) -> None:
        """Measure tick k (one noise draw), publish measurement (+ /clock)."""
        t_ns = self.k * self.ts_ns
        y = self.plant.outputs() + self.noise.sample()
        stamp = self._stamp_offset_ns + t_ns
        msg = self._measurement_cdr.encode_ns(stamp, y)
        clock = clock_cdr_ns(t_ns) if self.clock_pub is not None else None
        self._tick_msgs = (msg, clock)
        self._send()
        self._tick_published_at = self._sent_at
        if self._first_tick_at is None:
            self._first_tick_at = self._sent_at
        self.counters['ticks'] += 1
        self._awaiting = self.mode == 'lockstep'

    def _send(self) -> None:
        msg, clock = self._tick_msgs
        if self.mode == 'lockstep':
            # /clock first: it starts the longest answer chain (reference → setpoint →
            # controller), the measurement only has to be there when the setpoint is.
            self.clock_pub.publish(clock)
            self.measurement_pub.publish(msg)
        else:
            # sim: the measurement of t_k must be in before /clock fires the others' timers.
            self.measurement_pub.publish(msg)
            if clock is not None:
                self.clock_pub.publish(clock)
        self._sent_at = time.monotonic()

    def _step(self) -> None:
        """Integrate [t_k, t_k+1) with the held inputs (wall: the disturbance values stamped
        at or before t_k), k += 1."""
        self._apply_pending()
        if self.mode == 'wall':
            self._d_ahead.release(self.k * self.ts_ns, self.d)
        if self.mode != 'lockstep':        # remembered for ~/late_inputs
            self._integrated[self.k * self.ts_ns] = {**self.u, **self.d}
            self._integrated.pop((self.k - _LATE_MEMORY) * self.ts_ns, None)
            self._publish_applied(self.k)   # lockstep: only when the loop stops (_on_resend)
        start = time.perf_counter()
        self.plant.step(np.array([self.u[n] for n in self.plant.input_names]),
                        np.array([self.d[n] for n in self.plant.disturbance_names]), self.ts)
        self._step_s += time.perf_counter() - start
        self._steps += 1
        self.k += 1

    def _publish_applied(self, tick: int) -> None:
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
            self.applied_pub.publish(self._applied_cdr.encode_ns(
                self._stamp_offset_ns + tick * self.ts_ns, values))

    def _note_applied(self, names: Any) -> None:
        """Channels of ``manipulated`` received from a controller (in the plant's order)."""
        if any(n not in self._applied_names for n in names):
            known = set(self._applied_names) | set(names)
            self._applied_names = [n for n in self.plant.input_names if n in known]
            self._applied_cdr = JointStateCdr(self._applied_names, self._session)

    def _on_tick_timer(self) -> None:
        """wall/sim: close the previous interval with the latest inputs, publish tick k
        (wall: tick 0 at the announced origin, ``_start_timer``).

        wall: the measurement is that of the latest grid instant that has come,
        ``k = floor((now - t0) / ts)``, stamped ``origin + k·ts`` (its sample instant), never
        one ahead of it. A call that finds more than one period elapsed (a busy process, a
        late executor) integrates the periods in between with the inputs held, one step each,
        and does not publish them: they are counted as ``missed_samples`` (each tick is either
        published or counted, once). The executor may also call early (rclpy's EventsExecutor
        runs a timer that fell more than a period behind twice at once, the second call up
        to a period ahead of its instant). Integration stops after one period of work (a
        plant slower than real time), so parameter services and diagnostics still run; the
        tick reached is then published, stamped with its own (past) instant."""
        if self._paused():
            return                      # a call that was due when the pause came
        if self._tick_msgs is None:     # wall: tick 0 announced (_start_timer), not yet come
            if self.mode == 'wall' and self._wait_for(self._wall_t0_ns):
                self._publish_tick()
            return
        if self.mode != 'wall':
            self._step()
            self._publish_tick()
            return
        if not self._wait_for(self._wall_t0_ns + (self.k + 1) * self.ts_ns):
            return
        now_ns = time.monotonic_ns()
        due = max((now_ns - self._wall_t0_ns) // self.ts_ns, self.k + 1)
        steps = 0
        while self.k < due:
            self._step()
            steps += 1
            if time.monotonic_ns() - now_ns > self.ts_ns:
                break                   # behind real time: the rest at the next call
        self.counters['missed_samples'] += steps - 1   # integrated, never published
        self._publish_tick()

    def _wait_for(self, instant_ns: int) -> bool:
        """wall: is the timer's call for the steady-clock ``instant_ns``? A call more than
        half a period early is not (a made-up call, or one of the countdown to tick 0); one a
        little early waits for the instant."""
        ahead_ns = instant_ns - time.monotonic_ns()
        if ahead_ns > self.ts_ns // 2:
            return False
        if ahead_ns > 0:
            time.sleep(ahead_ns / 1e9)
        return True

    # --------------------------------------------------------------- inputs
    def _now_ns(self) -> int | None:
        """This plant's now in the stamps' time base: sim/lockstep the current tick; wall the
        time on its own grid (origin + steady time since tick 0), None before the origin is
        announced."""
        if self.mode != 'wall':
            return self.k * self.ts_ns
        if not self._announced:
            return None
        return self._stamp_offset_ns + time.monotonic_ns() - self._wall_t0_ns

    def _on_input(self, topic: str, msg: bytes) -> None:
        """An input message (CDR bytes of a JointState); one stamped more than
        ``max_future_stamp`` ahead of this plant's now is refused (``rejected_future``)."""
        flt = self.filters[topic]
        t_ns, names, accepted, new_reasons = flt.accept(topic, msg)
        if t_ns is not None and not self._future.admit(topic, t_ns, self._now_ns(),
                                                       time.monotonic_ns()):
            new_reasons += self._future.take_report()
            t_ns = None
        else:
            new_reasons += self._future.take_report()
        for reason in new_reasons:
            self.get_logger().warning(reason + ' (logged at most once per diagnostics period)')
        if t_ns is None:
            return                      # malformed or refused: no arrival, nothing taken
        now = time.monotonic()
        last = self._arrivals.get(topic)
        self._arrivals[topic] = (now, now - last[0] if last else 0.0)
        if self.mode != 'lockstep':
            self._take_latest(topic, t_ns, accepted)
            return
        current = self.k * self.ts_ns
        # a disturbance stamped before the tick is a re-sent one still in force (Held)
        low = current if topic == TOPIC_MANIPULATED else -1
        if t_ns is None or not low <= t_ns <= current + _LOOKAHEAD * self.ts_ns:
            return                      # malformed, a stale duplicate, or far ahead
        held = self.u if topic == TOPIC_MANIPULATED else self.d
        # A known channel with an ignored (non-finite) value still answers the
        # tick: its last valid value is kept.
        answered = {n: accepted.get(n, held[n]) for n in names if n in flt.known}
        # Answers for a later tick (the reference publishes ahead) wait in the inbox.
        self.inbox.put(topic, t_ns, answered)
        if self._awaiting and self.inbox.complete(current):
            self._advance(current)

    def _take_latest(self, topic: str, t_ns: int | None, accepted: dict[str, float]) -> None:
        """sim/wall: hold the newest values; report an answer that came after its tick
        was integrated (``~/late_inputs``, docs/nodes.md "Late answers")."""
        if t_ns is None:
            return                      # malformed (counted by the filter)
        if self._tick_msgs is not None and t_ns - self._stamp_offset_ns < self.k * self.ts_ns:
            self.counters['late_inputs'] += 1
            tick = (t_ns - self._stamp_offset_ns) // self.ts_ns * self.ts_ns
            used = self._integrated.get(tick, {})
            self.late_pub.publish(to_joint_state(t_ns, list(accepted),
                                                 [used.get(n, math.nan) for n in accepted]))
        if t_ns < self._held_stamp.get(topic, t_ns):
            if not self._future.back_on_clock(topic, self._held_stamp[topic], t_ns,
                                              self._now_ns()):
                return                  # older than the values held: out of order
            if topic == TOPIC_DISTURBANCE:
                self._d_ahead.clear()   # the stepped values waiting for their stamps
            for text in self._future.take_report():
                self.get_logger().warning(text)
        self._held_stamp[topic] = t_ns
        if topic == TOPIC_DISTURBANCE and self.mode == 'wall':
            # the reference publishes each instant ``wall.lead`` ahead: held until the step
            # that starts at its stamp (_step)
            self._d_ahead.put(t_ns - self._stamp_offset_ns, accepted)
            return
        (self.u if topic == TOPIC_MANIPULATED else self.d).update(accepted)
        if topic == TOPIC_MANIPULATED:
            self._note_applied(accepted)

    def _advance(self, t_ns: int) -> None:
        manipulated = self.inbox.values(t_ns, TOPIC_MANIPULATED)
        self._note_applied(manipulated)
        self.u.update(manipulated)
        self.d.update(self.inbox.values(t_ns, TOPIC_DISTURBANCE))
        self._awaiting = False
        self._step()
        self.inbox.drop_before(self.k * self.ts_ns)
        if self._paused():
            self._publish_applied(self.k - 1)
            return                      # un-pausing publishes the next tick
        self._next_tick()

    def _recorder_allows(self, tick: int) -> bool:
        """``lockstep.record_window``: tick may be published. Tick 1 waits until the recorder
        holds tick 0 whole — its receipt shows that every signal writer has matched the
        recorder's readers (a volatile writer sends nothing to a reader it has not matched
        yet) — later ticks run up to ``record_window`` ahead."""
        recorded = self._recorded_tick
        return not self._window or tick <= recorded + (self._window if recorded >= 0 else 1)

    def _next_tick(self) -> None:
        """Lockstep: publish tick k now, at its wall time (pacing), or once the recorder has
        acknowledged enough (``_recorder_allows``)."""
        if not self._recorder_allows(self.k):
            self._held_for_recorder = True      # _on_recorded publishes it
            return
        self._held_for_recorder = False
        if self._pace_timer is None or self._wait_ns() <= 0:
            self._publish_tick()
        else:                           # a one-shot at the tick's wall time
            self._pace_timer.timer_period_ns = self._wait_ns()
            self._pace_timer.reset()

    def _on_recorded(self, msg: Time) -> None:
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
        tick = (stamp_to_ns(msg) - self._stamp_offset_ns) // self.ts_ns
        if tick <= self._recorded_tick:
            return
        self._recorded_tick = tick
        if (self._held_for_recorder and not self._awaiting and not self._paused()
                and self._tick_msgs is not None):
            self._next_tick()

    # ------------------------------------------------------------- lockstep
    def _set_pacing(self, rtf: float) -> None:
        """rtf 0: next tick at once; rtf > 0: tick k at wall ``start + t_k / rtf``
        (a one-shot timer armed for each tick that is early, no polling)."""
        if self._pace_timer is not None:
            self.destroy_timer(self._pace_timer)
            self._pace_timer = None
        self._rtf = rtf
        if rtf > 0:
            self._wall_start = time.monotonic() - self._t() / rtf
            self._pace_timer = self.create_timer(self.ts / rtf, self._on_pace,
                                                 clock=steady_clock(), autostart=False)

    def _wait_ns(self) -> int:
        """Wall nanoseconds until tick k is due (<= 0: due)."""
        return int((self._wall_start + self._t() / self._rtf - time.monotonic()) * 1e9)

    def _on_pace(self) -> None:
        self._pace_timer.cancel()
        if self._awaiting or self._tick_msgs is None or self._paused():
            return
        wait = self._wait_ns()
        if wait <= 0:
            self._publish_tick()
        else:                           # woke a little early: sleep the rest on the timer
            self._pace_timer.timer_period_ns = wait
            self._pace_timer.reset()

    def _on_resend(self) -> None:
        """Re-send the last tick published if unanswered, or not yet held whole by the recorder
        (``record_window``: tick k−1 while k waits for it, e.g. tick 0 whose answers came before
        the recorder had matched their writers), for ``lockstep.resend_period`` — with
        ``record_window``, only once the recorder holds every tick before it (see
        ``_on_recorded``)."""
        if self._is_paused:             # paused: nothing is published, re-sends neither
            return
        last = self.k if self._awaiting else self.k - 1
        if self._window and self._recorded_tick < last - 1:
            return
        if ((self._awaiting or self._held_for_recorder) and self._tick_msgs is not None
                and time.monotonic() - self._sent_at >= self._resend_period):
            self._publish_applied(self.k - 1)
            self.counters['resent_ticks'] += 1
            self._send()

    # ----------------------------------------------------------- diagnostics
    def _pace_report(self) -> str:
        """wall and sim: '' while simulated time keeps its pace (1 s per wall second in wall,
        ``real_time_factor`` in sim), else how far behind it is and what a tick costs (e.g. a
        tiny ``integration_step``): measured over the time since the last report."""
        now, mark = time.monotonic(), self._pace_mark
        self._pace_mark = None if self._paused() else (now, self.k)
        step_ms = self._step_s / self._steps * 1e3 if self._steps else 0.0
        self._step_s, self._steps = 0.0, 0
        self._step_ms = step_ms
        if self.mode == 'lockstep' or self._paused() or mark is None or now - mark[0] < 0.5:
            return ''
        target = 1.0 if self.mode == 'wall' else float(self.params.values['real_time_factor'])
        rate = (self.k - mark[1]) * self.ts / (now - mark[0])
        if rate >= 0.9 * target:
            return ''
        return (f'behind real time: {rate:.3g}x instead of {target:g}x (plant.step takes '
                f'{step_ms:.3g} ms per {self.ts * 1e3:g} ms tick)')

    def _stall_report(self) -> str:
        """'' while the loop moves, else what the plant waits for and for how long.

        lockstep: tick k unanswered for ``STALL_RESENDS`` re-send periods (a node is down, or
        restarting): ``stalled <s> s at t = <t> s: waiting for manipulated.u (controller)``.
        wall/sim: ``manipulated`` silent for ``STALL_INTERVALS`` of its recent intervals (at
        least ``STALL_MIN_S``) after it had come: ``no manipulated (controller) for <s> s:
        inputs held``."""
        now = time.monotonic()
        if self._is_paused:
            return ''
        if self.mode == 'lockstep':
            waited = now - self._tick_published_at
            if not self._awaiting or waited < STALL_RESENDS * self._resend_period:
                return ''
            current = self.k * self.ts_ns
            missing = self.inbox.missing(current)
            # The reference publishes ahead (Held): once it has answered /clock t_k its
            # streams reach t_k+1. One that has not is behind, and the controller may wait
            # for its setpoint though the plant holds the disturbance of this tick.
            behind = self.inbox.held[TOPIC_DISTURBANCE].through < current + (self.ts_ns
                                                                               if self.k else 0)
            if TOPIC_DISTURBANCE in self.inbox.required and behind and \
                    TOPIC_DISTURBANCE not in missing:
                missing.append(TOPIC_DISTURBANCE)
            named = ', '.join(f'{m} ({_ANSWERED_BY.get(m.split(".")[0], "?")})' for m in missing)
            return f'stalled {waited:.3g} s at t = {self._t():g} s: waiting for {named}'
        never = self._never_received(now)
        if never:
            return never
        arrival = self._arrivals.get(TOPIC_MANIPULATED)
        if arrival is None:
            return ''
        silent = now - arrival[0]
        if silent < max(STALL_MIN_S, STALL_INTERVALS * arrival[1]):
            return ''
        return (f'no {TOPIC_MANIPULATED} ({_ANSWERED_BY[TOPIC_MANIPULATED]}) for {silent:.3g} s: '
                'inputs held')

    def _never_received(self, now: float) -> str:
        """wall/sim: '' or which input topics have sent nothing ``NEVER_RECEIVED_S`` after the
        first tick: ``waiting for manipulated (controller), disturbance (reference): nothing
        received in <s> s; inputs held at their initial values``."""
        if self._first_tick_at is None or now - self._first_tick_at < NEVER_RECEIVED_S:
            return ''
        topics = [TOPIC_MANIPULATED] if self.plant.input_names else []
        if self.plant.disturbance_names:
            topics.append(TOPIC_DISTURBANCE)
        missing = [t for t in topics if t not in self._arrivals]
        if not missing:
            return ''
        named = ', '.join(f'{t} ({_ANSWERED_BY[t]})' for t in missing)
        return (f'waiting for {named}: nothing received in {now - self._first_tick_at:.3g} s; '
                'inputs held at their initial values')

    def _log_stall(self, stall: str) -> None:
        """A stall is logged once when it starts (WARN, the diagnostics' text) and once when
        it ends; its kind is its text without the seconds, which grow."""
        kind = ' '.join(w for w in stall.split() if not any(c.isdigit() for c in w))
        if kind and kind != self._stall_logged:
            self.get_logger().warning(stall)
        elif not kind and self._stall_logged:
            self.get_logger().info('inputs arrive: the loop moves')
        self._stall_logged = kind

    def _publish_diagnostics(self) -> None:
        # the filters count per message; the totals are taken here, off the hot path
        self.counters['ignored_inputs'] = sum(f.ignored for f in self.filters.values())
        self.counters['out_of_range_inputs'] = sum(f.out_of_range for f in self.filters.values())
        self.counters['unknown_channels'] = sum(f.unknown for f in self.filters.values())
        self.counters['oversized_inputs'] = sum(f.oversized for f in self.filters.values())
        self.counters['rejected_future'] = self._future.refused
        for flt in self.filters.values():
            flt.rearm()                 # each kind of reason logged again at most once a period
        self._future.rearm_reports()
        status = DiagnosticStatus(name='plant', hardware_id=str(self.params.values.get('plant', '')))
        model = dict(self.plant.status)
        problems = []
        if self.counters['ignored_inputs']:
            problems.append(f"{self.counters['ignored_inputs']} ignored inputs")
        if self.counters['rejected_future']:
            problems.append(f"{self.counters['rejected_future']} inputs stamped in the future "
                            'refused')
        if model.get('clipped_flows'):
            problems.append(f"{model['clipped_flows']} clipped flows")
        if model.get('overflow'):
            problems.append('overflowing')
        behind = self._pace_report()
        if behind:
            problems.append(behind)
        stall = self._stall_report()
        self._log_stall(stall)
        if stall:
            problems.append(stall)
        status.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
        status.message = ', '.join(problems) or 'ok'
        items = {'clock_mode': self.mode, 'sim_time': f'{self._t():.9g}',
                 'time_origin_ns': self._stamp_offset_ns, **self.counters}
        items['paused'] = self._is_paused
        self._matched_sent = self._matched()
        items.update(self._matched_sent)
        items['step_time_ms'] = f'{self._step_ms:.4g}'
        if self.mode == 'lockstep' and self._awaiting:
            items['waiting_for'] = ', '.join(self.inbox.missing(self.k * self.ts_ns))
        for name, value in model.items():
            items[f'model.{name}'] = value
        for topic, flt in self.filters.items():
            items[f'ignored.{topic}'] = flt.ignored
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in items.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args: list[str] | None = None) -> int:
    """Console entry point plant_node; exit 2 with a one-line reason on bad parameters."""
    return run_node_main('plant_node', PlantNode, args)


if __name__ == '__main__':
    sys.exit(main())
