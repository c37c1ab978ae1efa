"""signal_bridge_node's parameters and its mapping, without rclpy (docs/signal_bridge.md).

Real drivers publish one typed scalar per topic; the loop speaks ``JointState`` channels
(docs/nodes.md, "Messages"). Per channel the bridge maps

* a driver's topic → ``measurement`` (``measurement.channels``; each ``measurement.<ch>.topic``
  of ``measurement.<ch>.type``), one ``JointState`` of that channel per driver message, stamped
  with the driver's ``header.stamp`` (a stamped ``sensor_msgs`` type) or, for ``Float64`` and a
  message whose stamp is zero, the wall clock on arrival (counted as ``receive_stamps``);
* ``manipulated`` → a driver's topic (``manipulated.channels``; ``manipulated.<ch>.topic`` of
  ``manipulated.<ch>.type``), one message per channel and ``manipulated`` message, a stamped
  type stamped with the ``manipulated`` stamp.

Hostile input is refused, counted and reported once per diagnostics period
(:meth:`SignalMapping.take_reasons`): a non-finite value, a stamp more than ``max_future_stamp``
ahead of the wall clock (``core/stamps.FutureStamps``), one older than the channel's last, a
measurement before the time origin, and on ``manipulated`` a malformed message, an unknown
channel or a value outside ``range.<ch>``. Times in integer nanoseconds.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from tank_control.core import ranges
from tank_control.core.ranges import channel_names
from tank_control.core.node_specs import diagnostics_period_param, max_future_stamp_param
from tank_control.core.params import ConfigError, ParamSpec, config_from, param, specs_of
from tank_control.core.stamps import FutureStamps, future_tolerance_ns

DIRECTIONS = ('measurement', 'manipulated')
#: ``measurement.publish``: a message per driver value, or one per instant with every channel
PUBLISH = ('each', 'sample')


@dataclass(frozen=True)
class ScalarType:
    """A message type holding one value: its ROS type name, the field, whether it has a
    ``header``."""

    ros_type: str
    field: str
    stamped: bool


#: ``<direction>.<ch>.type`` → the message (std_msgs/Float64 and the sensor_msgs scalars).
TYPES = {
    'Float64': ScalarType('std_msgs/msg/Float64', 'data', False),
    'Temperature': ScalarType('sensor_msgs/msg/Temperature', 'temperature', True),
    'FluidPressure': ScalarType('sensor_msgs/msg/FluidPressure', 'fluid_pressure', True),
    'RelativeHumidity': ScalarType('sensor_msgs/msg/RelativeHumidity', 'relative_humidity', True),
    'Illuminance': ScalarType('sensor_msgs/msg/Illuminance', 'illuminance', True),
    'Range': ScalarType('sensor_msgs/msg/Range', 'range', True),
}
_TOPIC = re.compile(r'^(~/|/)?[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$')
#: the loop's own topics, which a driver topic must not be (the bridge would feed itself)
LOOP_TOPICS = ('measurement', 'manipulated', 'setpoint', 'disturbance', 'time_origin')


@dataclass(frozen=True)
class BridgeNode:
    """signal_bridge_node's own parameters (the channels: :func:`channel_specs`)."""

    sample_time: float = param(0.1, 'the loop\'s sample time (the controller\'s): the grid of '
                               'the time origin, and the default of max_future_stamp',
                               unit='s', min=0.001, max=3600.0, read_only=True)
    announce_origin: bool = param(True, 'publish the latched time_origin (wall clock, on the '
                                  'first measurement\'s grid shifted by half a sample time) as '
                                  'plant_node does in wall mode; false when another node is the '
                                  'clock master of the loop', read_only=True)
    publish: str = param('each', 'each: one measurement message per driver value, holding its '
                         'channel, with the value\'s stamp; sample: at each instant origin + '
                         'j x sample_time of the wall clock one message holding every measurement '
                         'channel, each its latest value stamped at or before the instant, stamped '
                         'with the instant (controller_node samples a message that holds all its '
                         'outputs: a controller of several outputs needs sample)',
                         choices=PUBLISH, name='measurement.publish', read_only=True)
    max_future_stamp: float | None = max_future_stamp_param()
    diagnostics_period: float = diagnostics_period_param()

    def reason(self) -> str | None:
        if self.publish == 'sample' and not self.announce_origin:
            return ('measurement.publish: sample needs announce_origin true (the instants are '
                    'on the time origin the bridge announces)')
        return None


@dataclass(frozen=True)
class Channel:
    """One bridged channel: its topic and message type."""

    name: str
    topic: str
    type: str

    @property
    def scalar(self) -> ScalarType:
        return TYPES[self.type]


@dataclass(frozen=True)
class BridgeSettings:
    """Everything the bridge needs, checked."""

    node: BridgeNode
    measurement: tuple[Channel, ...]
    manipulated: tuple[Channel, ...]
    limits: ranges.Ranges = field(default_factory=ranges.Ranges)


def channel_specs(values: Mapping[str, Any],
                  actuator: Mapping[str, tuple[float, float]] | None = None
                  ) -> tuple[ParamSpec, ...]:
    """The channel parameters the start-up ``values`` name: the two lists, a topic and a type
    per channel, ``range.<ch>`` per manipulated channel (defaults ``actuator``: the
    controller's output limits)."""
    specs = []
    for direction in DIRECTIONS:
        names = channel_names(values, direction)
        specs.append(ParamSpec(f'{direction}.channels', names or [''],
                               f'{direction} channels (signal names); [\'\'] = none',
                               read_only=True))
        what = ('the driver topic the value is read from' if direction == 'measurement'
                else 'the driver topic the value is written to')
        for ch in names:
            specs.append(ParamSpec(f'{direction}.{ch}.topic', '', f'{what}, e.g. /tank/level',
                                   read_only=True))
            specs.append(ParamSpec(f'{direction}.{ch}.type', 'Float64',
                                   'its message type (std_msgs/Float64 or a sensor_msgs scalar)',
                                   choices=tuple(TYPES), read_only=True))
    specs += ranges.range_specs(channel_names(values, 'manipulated'), actuator)
    return tuple(specs)


def specs(values: Mapping[str, Any],
          actuator: Mapping[str, tuple[float, float]] | None = None) -> tuple[ParamSpec, ...]:
    """Every parameter of a signal_bridge_node started with ``values``."""
    return specs_of(BridgeNode) + channel_specs(values, actuator)


def topic_reason(topic: Any) -> str | None:
    """None if ``topic`` is a topic name a driver may use, else why not."""
    if not isinstance(topic, str) or not topic:
        return 'missing; allowed a topic name such as /tank/level'
    if not _TOPIC.match(topic):
        return (f'{topic!r} is not a topic name; allowed letters, digits, _ and / '
                '(e.g. /tank/level)')
    if topic.strip('/') in LOOP_TOPICS:
        return (f'{topic!r} is one of the loop\'s own topics ({", ".join(LOOP_TOPICS)}); '
                'allowed a driver\'s topic')
    return None


def settings_from(values: Mapping[str, Any],
                  actuator: Mapping[str, tuple[float, float]] | None = None) -> BridgeSettings:
    """Checked settings from parameter values; ConfigError naming the parameter."""
    own = {k: v for k, v in values.items() if k in {s.name for s in specs_of(BridgeNode)}}
    node = config_from(BridgeNode, own)
    channels: dict[str, list[Channel]] = {}
    topics: dict[str, str] = {}
    for direction in DIRECTIONS:
        channels[direction] = []
        for ch in channel_names(values, direction):
            name = f'{direction}.{ch}.topic'
            topic = values.get(name, '')
            reason = topic_reason(topic)
            if reason:
                raise ConfigError(f'{name}: {reason}')
            kind = values.get(f'{direction}.{ch}.type', 'Float64')
            if kind not in TYPES:
                raise ConfigError(f'{direction}.{ch}.type: {kind!r}; allowed one of '
                                  + ', '.join(TYPES))
            if topic in topics:
                raise ConfigError(f'{name}: {topic!r} is also {topics[topic]}; allowed one '
                                  'channel per topic')
            topics[topic] = name
            channels[direction].append(Channel(ch, topic, kind))
    if not channels['measurement'] and not channels['manipulated']:
        raise ConfigError('measurement.channels: no channel in measurement.channels nor in '
                          'manipulated.channels; allowed a list of names')
    limits = ranges.ranges_from(values, [c.name for c in channels['manipulated']], actuator)
    return BridgeSettings(node, tuple(channels['measurement']), tuple(channels['manipulated']),
                          limits)


#: the time origin is announced at least this long before the first measurement published
#: (as plant_node in wall mode: the reference's instant 0 comes first) [s]
ORIGIN_NOTICE_NS = 200_000_000
COUNTERS = ('received', 'published', 'receive_stamps', 'nonfinite', 'rejected_future',
            'out_of_order', 'before_origin', 'incomplete_samples', 'written', 'malformed',
            'unknown_channels', 'out_of_range')
#: ``measurement.publish: sample``: values held per channel (a driver faster than the loop)
MAX_HELD = 64
#: the counters that are refusals (a WARN on /diagnostics while any is non-zero)
REFUSALS = {'nonfinite': 'non-finite values refused',
            'rejected_future': 'values stamped in the future refused',
            'out_of_order': 'values older than the channel\'s last refused',
            'malformed': 'malformed manipulated messages refused',
            'unknown_channels': 'unknown manipulated channels ignored',
            'out_of_range': 'manipulated values outside range.* not written'}


class SignalMapping:
    """The bridge's arithmetic and checks, one call per message (no ROS here).

    ``measurement(ch, value, stamp_ns, now_ns)`` → the ``(stamp_ns, {ch: value})`` to publish
    on ``measurement``, or None (refused or before the time origin); ``manipulated(stamp_ns,
    names, values)`` → ``[(channel, value, stamp_ns)]`` to write. ``now_ns`` is the wall
    clock (ROS time) and ``mono_ns`` a monotonic clock (times the recovery of a stream refused
    as a clock step, ``FutureStamps``). ``origin_ns`` is the time origin once announced
    (:meth:`origin_for`), computed at the first measurement when ``announce_origin`` (then
    ``new_origin`` holds it until the node has published it), 0 without."""

    def __init__(self, settings: BridgeSettings) -> None:
        self.settings = settings
        node = settings.node
        self.ts_ns = round(node.sample_time * 1e9)
        self.future = FutureStamps(future_tolerance_ns(node.max_future_stamp, node.sample_time))
        self.counters = {key: 0 for key in COUNTERS}
        self.origin_ns: int | None = None if node.announce_origin else 0
        self.new_origin: int | None = None       # an origin to announce (the node clears it)
        self._last: dict[str, int] = {}          # channel → stamp of its last value taken
        self._held: dict[str, list[tuple[int, float]]] = {}   # publish sample: values taken
        self._sampled: int | None = None         # publish sample: the last instant published
        self._last_u: int | None = None
        self._reasons: list[str] = []
        self._reported: set[str] = set()
        self._inputs = {c.name for c in settings.manipulated}

    def origin_for(self, stamp_ns: int, now_ns: int) -> int:
        """The time origin to announce before a first measurement stamped ``stamp_ns``: on its
        grid shifted by half a sample time (a value arriving with up to half a sample time of
        jitter stays in its own controller instant), at least ``ORIGIN_NOTICE_NS`` after
        ``now_ns``. Sets ``origin_ns``."""
        base = stamp_ns - self.ts_ns // 2
        periods = max(0, -(-(now_ns + ORIGIN_NOTICE_NS - base) // self.ts_ns))
        self.origin_ns = base + periods * self.ts_ns
        return self.origin_ns

    def measurement(self, channel: str, value: float, stamp_ns: int | None, now_ns: int,
                    mono_ns: int) -> tuple[int, dict[str, float]] | None:
        """A driver's value of ``channel`` (``stamp_ns`` None or 0: the message has none)."""
        self.counters['received'] += 1
        topic = f'measurement.{channel}'
        if not stamp_ns:
            stamp_ns = now_ns
            self.counters['receive_stamps'] += 1
        if not math.isfinite(value):
            self._refuse('nonfinite', channel, f'{topic}: non-finite value {value!r} refused; '
                         'the last good value stays the latest')
            return None
        if not self.future.admit(channel, stamp_ns, now_ns, mono_ns):
            self.counters['rejected_future'] = self.future.refused
            self._reasons.extend(f'{topic}: {text}' for text in self.future.take_report())
            return None
        self._reasons.extend(f'{topic}: {text}' for text in self.future.take_report())
        last = self._last.get(channel)
        if last is not None and stamp_ns <= last:
            self._refuse('out_of_order', channel, f'{topic}: a value stamped at or before the '
                         f'last one ({(last - stamp_ns) / 1e9:.6g} s older) refused')
            return None
        origin = self.origin_ns
        if origin is None:                         # the first value: announce the origin
            origin = self.new_origin = self.origin_for(stamp_ns, now_ns)
        if stamp_ns < origin:
            self.counters['before_origin'] += 1
            return None
        self._last[channel] = stamp_ns
        if self.settings.node.publish == 'sample':
            held = self._held.setdefault(channel, [])
            held.append((stamp_ns, float(value)))
            del held[:-MAX_HELD]                   # bounded: the latest values only
            return None
        self.counters['published'] += 1
        return stamp_ns, {channel: float(value)}

    def sample(self, now_ns: int) -> tuple[int, dict[str, float]] | None:
        """``measurement.publish: sample``: the message of the latest instant ``origin +
        j·sample_time`` at or before ``now_ns`` not yet published, holding each channel's latest
        value stamped at or before it; None before the origin, when that instant was published,
        or while a channel has no such value (counted as ``incomplete_samples``)."""
        origin = self.origin_ns
        if origin is None or now_ns < origin:
            return None
        instant = origin + (now_ns - origin) // self.ts_ns * self.ts_ns
        if self._sampled is not None and instant <= self._sampled:
            return None
        values = {}
        for channel in self.settings.measurement:
            held = [(s, v) for s, v in self._held.get(channel.name, []) if s <= instant]
            if not held:
                self.counters['incomplete_samples'] += 1
                self._sampled = instant
                self._note('incomplete', f'measurement: no value of {channel.name} stamped at or '
                           f'before the instant {instant} ns; the instant is not published')
                return None
            values[channel.name] = held[-1][1]
            # what is older than the value used is never used again
            self._held[channel.name] = [(s, v) for s, v in self._held[channel.name]
                                        if s >= held[-1][0]]
        self._sampled = instant
        self.counters['published'] += 1
        return instant, values

    def held_before_origin(self) -> None:
        """A driver value not published because the node holds the time origin back (its
        readers not yet matched, as plant_node waits before tick 0): counted."""
        self.counters['received'] += 1
        self.counters['before_origin'] += 1

    def manipulated(self, stamp_ns: int, names: Sequence[str], values: Sequence[float]
                    ) -> list[tuple[str, float, int]]:
        """A ``manipulated`` message (already parsed): each bridged channel's value to write,
        refused when non-finite or outside ``range.<ch>`` (the driver keeps the last written);
        the whole message when older than the last one."""
        if len(names) != len(values) or len(set(names)) != len(names):
            self._refuse('malformed', 'shape', f'manipulated: malformed message ({len(names)} '
                         f'names, {len(values)} values) refused')
            return []
        if self._last_u is not None and stamp_ns < self._last_u:
            self._refuse('out_of_order', 'manipulated', 'manipulated: a message older than the '
                         'last one refused')
            return []
        self._last_u = stamp_ns
        out = []
        unknown = [n for n in names if n not in self._inputs]
        if unknown:
            self.counters['unknown_channels'] += len(unknown)
            self._note('unknown', f'manipulated: unknown channel(s) '
                       f'{", ".join(repr(n[:40]) for n in unknown[:3])} ignored; bridged: '
                       f'{", ".join(sorted(self._inputs)) or "none"}')
        for name, value in zip(names, values):
            if name not in self._inputs:
                continue
            if not math.isfinite(value):
                self._refuse('nonfinite', name, f'manipulated.{name}: non-finite value refused; '
                             'the driver keeps the last written')
                continue
            reason = self.settings.limits.reason(name, value)
            if reason is not None:
                self._refuse('out_of_range', name, f'manipulated: {reason} not written; the '
                             'driver keeps the last written')
                continue
            self.counters['written'] += 1
            out.append((name, float(value), stamp_ns))
        return out

    def malformed(self, reason: str) -> None:
        """A ``manipulated`` message that could not be read at all (``reason``): refused."""
        self._refuse('malformed', 'message', f'manipulated: malformed message refused ({reason})')

    def take_reasons(self) -> list[str]:
        """The refusals' reasons not reported yet this period (each kind once per channel)."""
        out, self._reasons = self._reasons, []
        return out

    def rearm(self) -> None:
        """A new diagnostics period: report each kind of refusal again."""
        self._reported.clear()

    def status(self) -> tuple[str, str]:
        """``('ok', 'ok')`` or ``('warn', 'N non-finite values refused, ...')`` (cumulative)."""
        problems = [f'{self.counters[key]} {text}' for key, text in REFUSALS.items()
                    if self.counters[key]]
        if self.counters['receive_stamps']:
            problems.append(f"{self.counters['receive_stamps']} values without a stamp stamped "
                            'on arrival')
        refused = any(self.counters[key] for key in REFUSALS)
        return ('warn' if refused else 'ok'), (', '.join(problems) or 'ok')

    def _refuse(self, counter: str, key: str, reason: str) -> None:
        self.counters[counter] += 1
        self._note(f'{counter}/{key}', reason)

    def _note(self, key: str, reason: str) -> None:
        if key not in self._reported:
            self._reported.add(key)
            self._reasons.append(reason)
