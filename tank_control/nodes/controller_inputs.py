"""The controller node's input checks: parse, count and log what an input carries.

Every input is hostile until checked (docs/nodes.md, "controller_node"): a malformed message,
one stamped in the future, unknown channels, non-finite or out-of-range values are counted
(``counters``, on /diagnostics) and logged at most once per diagnostics period; a rejected
value keeps the last valid one.
"""
from __future__ import annotations

import math
import time
from collections.abc import Mapping

import numpy as np
from rclpy.node import Node

from tank_control.core import ranges
from tank_control.core.interfaces import seconds
from tank_control.core.stamps import FutureStamps
from tank_control.nodes.messages import TOPIC_MEASUREMENT, parse_signal
from tank_control.nodes.protocol.controller import ControllerClock


class ControllerInputs(Node):
    """The checks of ``controller_node``'s inputs (a base class of ``ControllerNode``)."""

    counters: dict[str, int]
    _protocol: ControllerClock
    _future: FutureStamps
    _ranges: ranges.Ranges
    _outputs: tuple[str, ...]
    _limited: set[str]         # kinds of input reasons logged this diagnostics period
    _logged: set[str]

    def _parse(self, topic: str, msg: bytes) -> tuple[int, dict[str, float], str] | None:
        """``(stamp_ns, {channel: value}, header.frame_id)`` of an input (CDR bytes of a
        JointState), None when malformed (also more than ``MAX_NAMES`` names) or stamped more
        than ``max_future_stamp`` ahead of this node's now (each counted and logged, at most
        once per diagnostics period)."""
        try:
            t_ns, frame_id, names, values = parse_signal(msg)
        except ValueError as exc:
            self.counters['rejected_inputs'] += 1
            self._log_limited(f'{topic}/malformed', f'{topic}: malformed message ignored ({exc})')
            return None
        # lockstep: a measurement is at most one plant tick past the latest one (the protocol)
        tolerance = (self._protocol.measurement_tolerance_ns() if topic == TOPIC_MEASUREMENT
                     else None)
        admitted = self._future.admit(topic, t_ns, self._protocol.now_ns(), time.monotonic_ns(),
                                      tolerance)
        for text in self._future.take_report():
            self.get_logger().warning(text + ' (logged at most once per diagnostics period)')
        if not admitted:
            self.counters['rejected_future'] = self._future.refused
            return None
        return t_ns, dict(zip(names, values)), frame_id


    def _count_channels(self, topic: str, values: Mapping[str, float],
                        known: tuple[str, ...]) -> None:
        """Count (and log, rate-limited) what an input carries that this controller does not
        use: unknown channels, a message with none of its channels, non-finite values."""
        unknown = [n for n in values if n not in known]
        if unknown:
            self.counters['unknown_channels'] += len(unknown)
            shown = ', '.join(repr(n[:40]) for n in unknown[:3])
            more = f' and {len(unknown) - 3} more' if len(unknown) > 3 else ''
            self._log_limited(f'{topic}/unknown', f'{topic}: unknown channel(s) {shown}{more} '
                              f'ignored ({self.counters["unknown_channels"]} so far); known: '
                              f'{", ".join(known) or "none"}')
        if known and not any(n in values for n in known):
            self.counters['empty_inputs'] += 1
            self._log_limited(f'{topic}/empty', f'{topic}: message without any of the channels '
                              f'{", ".join(known)} ignored ({self.counters["empty_inputs"]} so '
                              'far)')
        nonfinite = [n for n in known if n in values and not math.isfinite(values[n])]
        if nonfinite:
            self.counters['nonfinite_values'] += len(nonfinite)
            self._log_limited(f'{topic}/nonfinite', f'{topic}: non-finite value for '
                              f'{", ".join(map(repr, nonfinite))} '
                              f'({self.counters["nonfinite_values"]} so far)')

    def refused_past(self, topic: str, t_ns: int, held_ns: int) -> None:
        """A setpoint or disturbance stamped before the setpoint held (wall/sim) or the last
        tick answered (lockstep) is not taken: counted (``rejected_past``), logged
        rate-limited with what to do (the protocol's ``past_fix``); the last valid value is
        kept."""
        self.counters['rejected_past'] += 1
        what = 'unstamped (stamp 0)' if t_ns == 0 else f'stamped {seconds(t_ns):.13g} s'
        self._log_limited(f'{topic}/past', f'{topic}: message {what} refused, older than '
                          f'{self._protocol.past_held} ({seconds(held_ns):.13g} s): the last '
                          f'valid value is kept ({self.counters["rejected_past"]} so far); '
                          f'{self._protocol.past_fix}')

    def _log_limited(self, key: str, text: str) -> None:
        """Log ``text`` unless a reason of kind ``key`` was logged this diagnostics period."""
        if key not in self._limited:
            self._limited.add(key)
            self.get_logger().warning(text + ' (logged at most once per diagnostics period)')

    def _reject_input(self, reason: str) -> None:
        self.counters['rejected_inputs'] += 1
        self._log_once(reason)

    def _log_once(self, text: str) -> None:
        if text not in self._logged:
            self._logged.add(text)
            self.get_logger().warning(text)

    def _finite_or_last(self, topic: str, values: Mapping[str, float], names: tuple[str, ...],
                        last: dict[str, float]) -> dict[str, float]:
        """Channels ``names`` from ``values``; a non-finite one or one outside its
        ``range.*`` is rejected (last valid kept)."""
        out = {}
        for name in names:
            if name not in values:
                continue
            reason = self._ranges.reason(name, values[name])
            if reason is None:
                out[name] = last[name] = values[name]
            else:
                self._reject_input(f'{topic}: {reason} ignored; last valid kept')
                if name in last:
                    out[name] = last[name]
        return out

    def _measurement_fault(self, y: np.ndarray) -> str:
        """'' for a good measurement, else 'non-finite' or 'out-of-range' (logged once)."""
        for name, value in zip(self._outputs, y.tolist()):
            reason = self._ranges.reason(name, value)
            if reason is not None:
                if math.isfinite(value):
                    self._log_once(f'{TOPIC_MEASUREMENT}: {reason} refused like a non-finite '
                                   'one (logged once)')
                    return 'out-of-range'
                return 'non-finite'
        return ''

