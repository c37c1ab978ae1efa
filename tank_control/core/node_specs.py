"""The node-level parameters of plant_node, controller_node and reference_node, declared once.

Besides its model's or controller's own parameters (the kinds' configurations) each node has
these: the clock, the tick and the diagnostics period. ``node_specs(node, kind)`` lists every
parameter a node declares; the in-process loop and the harness validate parameter files with
the same lists, so a misspelt name is refused alike everywhere.
"""
from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from tank_control.opcua.plant_params import endpoint_param, mode_reason   # no asyncua
from tank_control.core import ranges
from tank_control.core.control.kinds import registry as controllers
from tank_control.core.monitoring.assess import MonitorConfig
from tank_control.core.params import ConfigError, ParamSpec, param, specs_of, unknown_reason
from tank_control.core.plants.kinds import registry as plants
from tank_control.core.plants.actuator import ActuatorConfig
from tank_control.core.plants.noise import NoiseConfig
from tank_control.core.stamps import (FUTURE_STAMP_SAMPLES, LOCKSTEP_AHEAD_TICKS, RECOVER_MESSAGES,
                                      RECOVER_S)

CLOCK_MODES = ('wall', 'sim', 'lockstep')
RTF_TINY = 1e-3
"""Smallest non-zero ``real_time_factor``: the plant's tick timer ``sample_time /
real_time_factor`` (at most 3.6e6 s) stays far inside rclpy's int64 nanoseconds."""
NODES = ('plant', 'controller', 'reference')
ROS_OWN = ('use_sim_time', 'start_type_description_service')
"""Parameters rclpy declares itself; accepted in every node section and left to rclpy (also
``qos_overrides.*``)."""


def is_ros_own(name: str) -> bool:
    """True for a parameter rclpy itself reads (``use_sim_time``, ``qos_overrides.*``, ...)."""
    return name in ROS_OWN or name.startswith('qos_overrides.')


def diagnostics_period_param() -> Any:
    return param(1.0, 'period of /diagnostics', unit='s, wall clock', min=0.05, max=60.0,
                 read_only=True)


def max_future_stamp_param() -> Any:
    return param(None, 'refuse an input message stamped more than this ahead of the node\'s own '
                 'now (wall: its clock; sim: its /clock time; lockstep: the current tick, and at '
                 f'least {LOCKSTEP_AHEAD_TICKS} sample times: the reference publishes ahead); '
                 'counted as rejected_future in /diagnostics. A stream refused for '
                 f'{RECOVER_S:g} s and {RECOVER_MESSAGES} messages without a break is a clock step '
                 f'and is taken again (docs/nodes.md). 0 = {FUTURE_STAMP_SAMPLES} x sample_time',
                 unit='s', min=0.0, max=3600.0, zero=None, read_only=True)


@dataclass(frozen=True)
class PlantNode:
    """plant_node's own parameters (the clock master)."""

    plant: str = param('fopdt', 'plant model: ' + ', '.join(plants.KINDS), read_only=True)
    sample_time: float = param(0.1, 'plant tick: measurements are published every sample_time; '
                               'in sim/lockstep tick k is at k * sample_time', unit='s',
                               min=1e-4, max=3600.0, read_only=True)
    clock_mode: str = param('wall', 'wall: real time; sim: the plant publishes /clock at '
                            'real_time_factor x real time; lockstep: /clock advances when every '
                            'answer of a tick arrived', choices=CLOCK_MODES, read_only=True)
    real_time_factor: float = param(1.0, 'simulated seconds per wall second in sim/lockstep '
                                    '(lockstep: 0 = as fast as possible); a non-zero factor is '
                                    f'at least {RTF_TINY:g} (a tick of up to 3600 s paced at '
                                    'it is still a timer period rclpy can hold)', min=0.0,
                                    max=1e6, tiny=RTF_TINY)
    resend_period: float = param(0.5, 'lockstep: re-send the current tick when its answers have '
                                 'not come within this wall time', unit='s', min=0.01, max=60.0,
                                 name='lockstep.resend_period')
    paused: bool = param(False, 'sim and lockstep: hold the current tick (simulated time stops) '
                         'until set to false; wall: hold the first tick only; lets a recorder '
                         'join before tick 0', name='lockstep.paused')
    wait_for_reference: bool = param(True, 'lockstep: also wait for the reference disturbance '
                                     'message of each tick', name='lockstep.wait_for_reference',
                                     read_only=True)
    record_window: int = param(0, 'lockstep: ticks the plant may run ahead of a recorder that '
                               'acknowledges on `recorded` the last tick it holds whole (0: none '
                               'waited for; at most 8, so that the signal publishers\' keep-last '
                               '10 still hold every tick the recorder has not taken)',
                               min=0, max=8, name='lockstep.record_window', read_only=True)
    max_future_stamp: float | None = max_future_stamp_param()
    diagnostics_period: float = diagnostics_period_param()
    opcua_endpoint: str = endpoint_param()

    def reason(self) -> str | None:
        reason = mode_reason(self.clock_mode, self.opcua_endpoint)    # lockstep refused
        if reason:
            return reason
        if self.clock_mode == 'sim' and self.real_time_factor <= 0:
            return (f'real_time_factor: {self.real_time_factor:g} with clock_mode sim; allowed '
                    f'[{RTF_TINY:g}, 1e6] (0 = as fast as possible exists in lockstep only)')
        return None


@dataclass(frozen=True)
class ControllerNode:
    """controller_node's own parameters."""

    controller: str = param('pid', 'controller kind (set at start-up): '
                            + ', '.join(controllers.KINDS), read_only=True)
    clock_mode: str = param('auto', 'auto: lockstep answering with use_sim_time, else wall; '
                            'wall: wall timer every sample_time; sim: timer on /clock; lockstep: '
                            'answer each plant tick stamped t_k once measurement and setpoint of '
                            't_k are in', choices=('auto', *CLOCK_MODES), read_only=True)
    trigger: str = param('measurement', 'wall: measurement = compute and publish on the arrival '
                         'of each measurement that reaches a new sample instant, stamped with its '
                         'stamp (sample, compute, actuate in one cycle; the timer only watches for '
                         'stale measurements); timer = sample the latest data on a wall timer '
                         'every sample_time, stamped with the wall time. sim/lockstep: not used',
                         choices=('measurement', 'timer'), read_only=True)
    stale_samples: int = param(3, 'wall/sim: samples without a measurement after which it is '
                               'stale (hold or fail-safe output)', min=1, max=1000)
    max_future_stamp: float | None = max_future_stamp_param()
    diagnostics_period: float = diagnostics_period_param()


@dataclass(frozen=True)
class ReferenceNode:
    """reference_node's own parameters (its channels: ``core/reference.py``)."""

    sample_time: float = param(1.0, 'publishing period in wall mode; in sim/lockstep the '
                               'reference answers every /clock tick instead', unit='s',
                               min=1e-6, max=3600.0)
    lead: float = param(0.007, 'with clock_mode wall: publish each instant\'s values this long '
                        'before it, stamped with the instant (at most half of sample_time); '
                        'the nodes of this package hold them until the instant, so the setpoint '
                        'of t_k is there before the measurement of t_k; 0: at the instant. '
                        '7 ms: no multiple of the usual plant periods (10, 20, 50, 100 ms), so '
                        'the publication falls between two plant ticks, not on one',
                        unit='s, wall clock', min=0.0, max=1.0, name='wall.lead')
    clock_mode: str = param('wall', 'wall: publish every sample_time on a wall timer; '
                            'sim/lockstep (also implied by use_sim_time): answer every /clock '
                            'tick, stamped t_k', choices=CLOCK_MODES, read_only=True)
    lookahead: int = param(6, 'with clock_mode lockstep: on /clock t_k the schedules are '
                           'published up to this many ticks ahead, one message per change, and '
                           'a message at t_k+lookahead whenever the last one is older than '
                           't_k+1 (zero-order hold: a message holds until the next one); the '
                           'nodes of this package know the values of a tick once a message '
                           'stamped at or after it came. 0: every tick answered when its /clock '
                           'comes. Live changes act from the first tick not yet published. Never '
                           'in sim (there every tick is answered, stamped t_k)', unit='ticks',
                           min=0, max=8, name='lockstep.lookahead', read_only=True)


def plant_channels(kind: str) -> tuple[str, ...]:
    """The channels a plant_node simulating ``kind`` receives: its inputs and disturbances."""
    model = plants.get_kind(kind).make({})      # build may be a factory, not the class
    return (*model.input_names, *model.disturbance_names)


def controller_channels(kind: str, values: Mapping[str, Any] | None = None) -> tuple[str, ...]:
    """The channels a controller_node running ``kind`` receives: its measured outputs (also the
    setpoints' channels, as ``output_names`` of ``values`` or the kind's default) and measured
    disturbances."""
    controller_kind = controllers.get_kind(kind)
    defaults: dict[str, Any] = {s.name: s.default for s in controller_kind.specs()}
    outputs = (values or {}).get('output_names', defaults.get('output_names', []))
    if not isinstance(outputs, (list, tuple)) or not all(isinstance(n, str) for n in outputs):
        outputs = defaults.get('output_names', [])     # a bad value is refused by its spec
    return (*outputs, *controller_kind.disturbances)


def controller_input_limits(controller_values: Mapping[str, Any] | None
                            ) -> dict[str, tuple[float, float]]:
    """The output limits ``{input channel: (lo, hi)}`` of the controller with parameter values
    ``controller_values`` (its kind's ``input_limits``); {} without values, without limits, or
    for values that do not make a controller (the controller refuses them itself)."""
    if not controller_values:
        return {}
    # scenario imports this module
    from tank_control.core.scenario import controller_setup
    try:
        setup = controller_setup(controller_values)
    except (ConfigError, ValueError, ArithmeticError):
        return {}
    kind = setup.kind
    if kind.input_limits is None:
        return {}
    return dict(kind.input_limits(setup.settings))


def actuator_defaults(controller_values: Mapping[str, Any] | None
                      ) -> dict[str, tuple[float, float]]:
    """Default ``range.*`` of the plant inputs a controller with parameter values
    ``controller_values`` drives (``ranges.actuator_ranges`` of its output limits)."""
    limits = controller_input_limits(controller_values)
    return ranges.actuator_ranges(limits) if limits else {}


def plant_specs(kind: str, controller_values: Mapping[str, Any] | None = None
                ) -> tuple[ParamSpec, ...]:
    """Every parameter of a plant_node simulating ``kind``; ``controller_values``: those of the
    controller driving it, whose output limits set the inputs' default ranges."""
    return (specs_of(PlantNode) + specs_of(NoiseConfig) + specs_of(ActuatorConfig)
            + plants.get_kind(kind).specs()
            + ranges.range_specs(plant_channels(kind), actuator_defaults(controller_values)))


def controller_specs(kind: str, values: Mapping[str, Any] | None = None
                     ) -> tuple[ParamSpec, ...]:
    """Every parameter of a controller_node running ``kind`` (``values``: its parameter values,
    whose ``output_names`` name the ``range.*`` parameters)."""
    return (specs_of(ControllerNode) + controllers.get_kind(kind).specs()
            + ranges.range_specs(controller_channels(kind, values)) + specs_of(MonitorConfig))


def kind_of(node: str, values: dict[str, Any]) -> str:
    """The plant or controller kind the values select (the declared default if absent)."""
    name = 'plant' if node == 'plant' else 'controller'
    cls = PlantNode if node == 'plant' else ControllerNode
    value = values.get(name, cls.__dataclass_fields__[name].default)
    (plants if node == 'plant' else controllers).get_kind(value)   # ConfigError if unknown
    return str(value)


def unknown_names(specs: tuple[ParamSpec, ...], values: dict[str, Any]) -> None:
    """``ConfigError`` for the first name in ``values`` that no spec declares (ROS's own
    parameters such as ``use_sim_time`` pass), with the nearest known name."""
    known = {s.name for s in specs}
    for name in values:
        if name not in known and not is_ros_own(name):
            raise ConfigError(unknown_reason(name, known))


def all_names() -> frozenset[str]:
    """Every parameter name some node of this package declares (any plant or controller kind,
    the reference's own; not the reference's channel fields, which depend on its channels)."""
    return _all_names(tuple((name, id(kind)) for name, kind in plants.KINDS.items()),
                      tuple((name, id(kind)) for name, kind in controllers.KINDS.items()))


@functools.lru_cache(maxsize=4)
def _all_names(plant_kinds: tuple, controller_kinds: tuple) -> frozenset[str]:
    """Computed once per content of the kind tables (the arguments identify it)."""
    specs = specs_of(ReferenceNode)
    specs += tuple(s for kind in plants.KINDS for s in plant_specs(kind))
    specs += tuple(s for kind in controllers.KINDS for s in controller_specs(kind))
    return frozenset(s.name for s in specs)


def declared_anywhere(name: str) -> bool:
    """True if some node of this package declares ``name``: a value a node does not know may
    then come from a ``/**`` section meant for another node, not from a typo."""
    return (is_ros_own(name) or name.split('.')[0] in ('setpoint', 'disturbance', 'range')
            or name in all_names())
