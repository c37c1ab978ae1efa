"""The reference's clock protocol (docs/nodes.md, "reference_node"), without rclpy.

``reference_clock(mode)`` picks the class once: ``LockstepReference`` makes the schedules known
``lockstep.lookahead`` ticks ahead under zero-order hold (a message per change, ``HeldStream``),
``SimReference`` answers each ``/clock`` tick once (idempotent), ``WallReference`` publishes
every ``sample_time`` of plant time from the plant's ``time_origin`` on, ``wall.lead`` early.
Each call returns the messages to publish as ``(topic, CDR bytes)``; the schedules are the
host's (``ReferenceHost``). Times in integer ns.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from tank_control.core.interfaces import seconds
from tank_control.core.reference import Reference
from tank_control.nodes.cdr import JointStateCdr

#: the topics (as nodes/messages.py names them)
SETPOINT, DISTURBANCE = 'setpoint', 'disturbance'

Messages = list[tuple[str, bytes]]


class ReferenceHost(Protocol):
    @property
    def reference(self) -> Reference: ...

    def apply_pending(self, t: float) -> None: ...

    def info(self, text: str) -> None: ...


class ReferenceClock:
    """Common state: the latest instant published and the encoders by channel names."""

    mode = ''
    follows_clock = True     # answers /clock (sim, lockstep); wall: the plant's time_origin

    def __init__(self, host: ReferenceHost, lookahead: int) -> None:
        self.host = host
        self.last_t = 0.0                  # the latest instant published (lockstep: evaluated) [s]
        self._encoders: dict[tuple[str, ...], JointStateCdr] = {}

    def encoder(self, names: tuple[str, ...]) -> JointStateCdr:
        encoder = self._encoders.get(names)
        if encoder is None:
            encoder = self._encoders[names] = JointStateCdr(names)
        return encoder

    def _evaluate(self, stamp_ns: int, t: float) -> tuple[bytes, bytes]:
        """The setpoint and disturbance messages of instant ``t`` [s], stamped ``stamp_ns``
        (accepted parameter changes act from it on)."""
        self.last_t = max(self.last_t, t)
        self.host.apply_pending(t)
        ref = self.host.reference
        sp = self.encoder(ref.setpoint_names).encode_ns(stamp_ns, ref.setpoints(t).tolist())
        dist = self.encoder(ref.disturbance_names).encode_ns(stamp_ns,
                                                               ref.disturbances(t).tolist())
        return sp, dist

    def clock(self, t_ns: int) -> Messages:
        """A /clock tick ``t_ns`` (sim, lockstep)."""
        return []

    origin_ns: int | None = None           # wall: the plant's time origin

    def origin(self, origin_ns: int) -> bool:
        """The plant's time origin (wall); True when the grid restarts from it."""
        return False

    def timer(self, now_ns: int, period_ns: int, lead_ns: int) -> tuple[Messages, int]:
        """wall: the messages due at ``now_ns`` and the wait until the next [ns]."""
        return [], period_ns


class HeldStream:
    """lockstep: one topic's messages under zero-order hold (``lockstep.lookahead``): a message
    per change of its values, and one at the horizon whenever the consumers would otherwise
    not know the next tick (``nodes/clock.Held`` is the consumers' side)."""

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.last: tuple[tuple[str, ...], tuple[float, ...]] | None = None   # the latest message's
        self.sent: list[tuple[int, bytes]] = []   # from the one in force at the tick on

    def offer(self, stamp_ns: int, names: tuple[str, ...], values: tuple[float, ...],
              encoder: Callable[[tuple[str, ...]], JointStateCdr], out: Messages) -> None:
        """The values at ``stamp_ns``: published when they differ from the last message's."""
        if (names, values) != self.last:
            self._send(stamp_ns, names, values, encoder(names), out)

    def hold(self, stamp_ns: int, need_ns: int,
             encoder: Callable[[tuple[str, ...]], JointStateCdr], out: Messages) -> None:
        """Publish the values held at ``stamp_ns`` if no message is stamped at or after
        ``need_ns`` (the next tick the consumers must know)."""
        if self.last is not None and self.sent[-1][0] < need_ns:
            names, values = self.last
            self._send(stamp_ns, names, values, encoder(names), out)

    def _send(self, stamp_ns: int, names: tuple[str, ...], values: tuple[float, ...],
              encoder: JointStateCdr, out: Messages) -> None:
        msg = encoder.encode_ns(stamp_ns, values)
        self.last = (names, values)
        self.sent.append((stamp_ns, msg))
        out.append((self.topic, msg))

    def prune(self, t_ns: int) -> None:
        """Keep the message in force at ``t_ns`` and the later ones (what a re-send sends)."""
        keep = 0
        while keep + 1 < len(self.sent) and self.sent[keep + 1][0] <= t_ns:
            keep += 1
        del self.sent[:keep]

    def resend(self, out: Messages) -> None:
        out.extend((self.topic, msg) for _, msg in self.sent)


class LockstepReference(ReferenceClock):
    """Zero-order hold only in an explicit lockstep: in sim the others use the latest message,
    which must be the current tick's (use_sim_time alone does not tell sim from lockstep)."""

    mode = 'lockstep'

    def __init__(self, host: ReferenceHost, lookahead: int) -> None:
        super().__init__(host, lookahead)
        self.lookahead = lookahead
        self._last_clock: int | None = None
        self._streams = (HeldStream(SETPOINT), HeldStream(DISTURBANCE))
        self._period_ns: int | None = None  # the plant's tick, from two /clock ticks
        self._horizon_ns = -1               # the latest instant evaluated [ns]

    def clock(self, t_ns: int) -> Messages:
        """On /clock t_k make the schedules known through t_k + ``lookahead`` ticks
        (zero-order hold: a message per change, ``HeldStream``), so that the controller and
        the plant of the next ticks wait for nobody but each other; a re-sent /clock t_k gets
        again every message from the one in force at t_k on."""
        out: Messages = []
        if self._last_clock is not None and t_ns < self._last_clock:
            # /clock went back: the plant (re)started, a new run
            self.host.info('/clock restarted: answering a new run')
            self._last_clock, self._period_ns, self._horizon_ns = None, None, -1
            self.last_t = 0.0
            self._streams = (HeldStream(SETPOINT), HeldStream(DISTURBANCE))
        if self._last_clock is None:
            self.host.info(f'first /clock tick {seconds(t_ns):g} s: answering the plant')
        if t_ns == self._last_clock:             # the plant re-sent tick k
            for stream in self._streams:
                stream.resend(out)
            return out
        if self._last_clock is not None:     # the plant's ticks are evenly spaced
            step = t_ns - self._last_clock
            self._period_ns = step if self._period_ns is None else min(self._period_ns, step)
        self._last_clock = t_ns
        period = self._period_ns
        ahead = self.lookahead if period else 0
        target = t_ns + ahead * (period or 0)
        j = t_ns if self._horizon_ns < t_ns or not period else self._horizon_ns + period
        setpoints, disturbances = self._streams
        while j <= target:
            t = seconds(j)
            self.last_t = max(self.last_t, t)
            self.host.apply_pending(t)
            ref = self.host.reference
            setpoints.offer(j, ref.setpoint_names, tuple(ref.setpoints(t).tolist()),
                            self.encoder, out)
            disturbances.offer(j, ref.disturbance_names, tuple(ref.disturbances(t).tolist()),
                               self.encoder, out)
            if not period:
                break                            # tick 0: the tick period is not known yet
            j += period
        self._horizon_ns = max(self._horizon_ns, target)
        need = t_ns + (period or 0) if ahead else t_ns   # the consumers' next tick
        for stream in self._streams:
            stream.hold(self._horizon_ns, need, self.encoder, out)
            stream.prune(t_ns)
        return out


class SimReference(ReferenceClock):
    """sim: answer tick t_k once (idempotent: a re-sent /clock gets the same messages)."""

    mode = 'sim'

    def __init__(self, host: ReferenceHost, lookahead: int) -> None:
        super().__init__(host, lookahead)
        self._last_clock: int | None = None
        self._answered: dict[int, tuple[bytes, bytes]] = {}

    def clock(self, t_ns: int) -> Messages:
        if self._last_clock is not None and t_ns < self._last_clock:
            # /clock went back: the plant (re)started, a new run (the plant re-sends only its
            # current tick, so an earlier one is no duplicate; its tick 0 may have been missed)
            self.host.info('/clock restarted: answering a new run')
            self._answered.clear()
            self._last_clock = None
            self.last_t = 0.0
        if self._last_clock is not None and t_ns < self._last_clock:
            return []                     # a stale duplicate of an earlier tick
        if self._last_clock is None:
            self.host.info(f'first /clock tick {seconds(t_ns):g} s: answering the plant')
        cached = self._answered.get(t_ns)
        if t_ns == self._last_clock and cached is not None:   # the plant re-sent tick k
            return [(SETPOINT, cached[0]), (DISTURBANCE, cached[1])]
        self._last_clock = t_ns
        for stamp in [s for s in self._answered if s < t_ns]:
            del self._answered[stamp]
        if cached is not None:
            return []
        sp, dist = self._answered[t_ns] = self._evaluate(t_ns, seconds(t_ns))
        return [(SETPOINT, sp), (DISTURBANCE, dist)]


class WallReference(ReferenceClock):
    """wall: the latest instant of plant time reached (``wall.lead`` early) on a grid from the
    plant's time origin; the consumers hold values stamped ahead until their instant
    (``nodes/clock.Scheduled``)."""

    mode = 'wall'
    follows_clock = False

    def __init__(self, host: ReferenceHost, lookahead: int) -> None:
        super().__init__(host, lookahead)
        self.origin_ns: int | None = None
        self._last_t_ns = -1

    def origin(self, origin_ns: int) -> bool:
        """The plant's time origin; True when it is new (the grid restarts from it)."""
        if origin_ns == self.origin_ns:
            return False
        if self.origin_ns is not None:
            self.host.info('new plant time origin (the plant restarted): schedule restarts at 0')
        self.origin_ns, self._last_t_ns, self.last_t = origin_ns, -1, 0.0
        return True

    def timer(self, now_ns: int, period_ns: int, lead_ns: int) -> tuple[Messages, int]:
        """At ROS time ``now_ns``: the messages of the latest instant reached (if not yet
        published; instant j is published at t_j - lead, stamped t_j, ``lead_ns`` at most half
        a period) and the wait until the next one [ns]."""
        assert self.origin_ns is not None
        lead_ns = min(lead_ns, period_ns // 2)
        elapsed = now_ns - self.origin_ns + lead_ns
        if elapsed < 0:                  # before the plant's tick 0: wait for instant 0
            return [], -elapsed
        t_ns = elapsed // period_ns * period_ns      # the latest instant reached
        out: Messages = []
        if t_ns > self._last_t_ns:
            self._last_t_ns = t_ns
            sp, dist = self._evaluate(self.origin_ns + t_ns, seconds(t_ns))
            out = [(SETPOINT, sp), (DISTURBANCE, dist)]
        return out, t_ns + period_ns - elapsed


_REFERENCES: dict[str, type[ReferenceClock]] = {
    'lockstep': LockstepReference, 'sim': SimReference, 'wall': WallReference}


def reference_clock(clock_mode: str, use_sim_time: bool) -> type[ReferenceClock]:
    """The protocol class: lockstep only when configured (zero-order hold); /clock ticks
    answered one by one in sim and with ``use_sim_time`` (the harness sets it); else wall."""
    if clock_mode == 'wall' and use_sim_time:
        clock_mode = 'sim'
    return _REFERENCES.get(clock_mode, SimReference)
