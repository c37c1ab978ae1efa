"""A scenario file as core objects: the plant, controller and reference the nodes would build.

A scenario is a ROS 2 parameter file (``core/params_file.py``) with a section per node
(``plant``, ``controller``, ``reference``), optionally ``/**`` for every node and ``harness``
for the harness. :func:`plant_setup`, :func:`controller_setup` and :func:`reference_setup`
validate one node's values exactly as that node does at start-up (unknown names refused with
the nearest known one) and build its core objects; :func:`build` and :func:`run_in_process`
run the whole loop through ``core/loop.py``, which a lockstep ROS run reproduces.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tank_control.core import node_specs, params_file, ranges
from tank_control.core.control.kinds import registry as controllers
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.interfaces import Controller, Plant
from tank_control.core.loop import Guards, run_loop, sample_time_reason
from tank_control.core.monitoring.assess import PREFIX as MONITOR_PREFIX
from tank_control.core.monitoring.assess import MonitorConfig
from tank_control.core.trace import Trace
from tank_control.core.node_specs import ControllerNode, PlantNode, ReferenceNode
from tank_control.core.params import (ConfigError, coerce, config_from, names_of, specs_of,
                                      unknown_reason, values_of)
from tank_control.core.plants.kinds import registry as plants
from tank_control.core.plants.actuator import ActuatorConfig, with_actuator
from tank_control.core.plants.kinds.base import PlantKind
from tank_control.core.plants.noise import MeasurementNoise, NoiseConfig
from tank_control.core.reference import Reference, channel_specs, reference_from_params

HARNESS = 'harness'
SECTIONS = (*node_specs.NODES, HARNESS, params_file.WILDCARD)


def _own(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    names = names_of(cls)
    return {k: v for k, v in values.items() if k in names}


# ----------------------------------------------------------------------------------- plant
@dataclass(frozen=True)
class PlantSetup:
    """plant_node's settings: its own, the noise, the model kind and the model's config, the
    actuator faults on its inputs."""

    node: PlantNode
    noise: NoiseConfig
    kind: PlantKind
    model: Any
    ranges: ranges.Ranges = ranges.Ranges()
    """plausible ranges of the inputs and disturbances it receives (``range.*``)"""
    actuator: ActuatorConfig = ActuatorConfig()
    """faults between the received inputs and the model (``actuator.*``, core/plants/actuator.py)"""

    def build_plant(self) -> Plant:
        """The model, behind the actuator faults when any is on (every kind alike)."""
        return with_actuator(self.kind.build(self.model), self.actuator)

    def build_noise(self, n_outputs: int) -> MeasurementNoise:
        """The seeded measurement noise (one ``sample()`` per tick)."""
        try:
            return MeasurementNoise(n_outputs, self.noise.noise_std, seed=self.noise.seed)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None


def plant_setup(values: Mapping[str, Any],
                controller_values: Mapping[str, Any] | None = None) -> PlantSetup:
    """plant_node's settings from its parameter values (``controller_values``: the controller's,
    whose output limits set the inputs' default ranges); ``ConfigError`` with the reason."""
    kind = plants.get_kind(node_specs.kind_of('plant', dict(values)))
    node_specs.unknown_names(node_specs.plant_specs(kind.name), dict(values))
    model_names = {s.name for s in kind.specs()}
    node = config_from(PlantNode, _own(PlantNode, values))
    model = config_from(kind.config, {k: v for k, v in values.items() if k in model_names})
    reason = kind.tick_reason(model, node.sample_time) if kind.tick_reason else None
    if reason:
        raise ConfigError(reason)
    actuator = config_from(ActuatorConfig, _own(ActuatorConfig, values))
    model_class: Any = kind.build                  # a plant class: its input_names
    actuator.vectors(model_class.input_names)      # one value or one per input channel
    return PlantSetup(
        node=node,
        noise=config_from(NoiseConfig, _own(NoiseConfig, values)),
        kind=kind,
        model=model,
        ranges=ranges.ranges_from(values, node_specs.plant_channels(kind.name),
                                  node_specs.actuator_defaults(controller_values)),
        actuator=actuator)


# ------------------------------------------------------------------------------ controller
@dataclass(frozen=True)
class ControllerSetup:
    """controller_node's settings: its own, the controller kind and the kind's settings."""

    node: ControllerNode
    kind: ControllerKind
    settings: Settings
    ranges: ranges.Ranges = ranges.Ranges()
    """plausible ranges of the measurements, setpoints and disturbances it reads"""
    monitor: MonitorConfig = MonitorConfig()
    """its loops' performance monitoring (``monitor.*``, docs/monitoring.md)"""

    def build_controller(self) -> Controller:
        return controllers.build(self.kind, self.settings)

    def values(self) -> dict[str, Any]:
        """Every parameter value of the node (its own and the kind's, derived ones included,
        the ranges)."""
        return {**values_of(self.node), **self.settings.values,
                **{ranges.name_of(c): list(b) for c, b in self.ranges.bounds.items()},
                **values_of(self.monitor)}


def controller_setup(values: Mapping[str, Any], given: Iterable[str] | None = None
                     ) -> ControllerSetup:
    """controller_node's settings from its parameter values (``given``: the names the user set,
    default all; a tuning rule's gains among them must agree with the rule)."""
    kind = controllers.get_kind(node_specs.kind_of('controller', dict(values)))
    node_specs.unknown_names(node_specs.controller_specs(kind.name, values), dict(values))
    node_names = set(names_of(ControllerNode))
    own = {k: v for k, v in values.items() if k not in node_names and not node_specs.is_ros_own(k)
           and not k.startswith((ranges.PREFIX, MONITOR_PREFIX))}
    settings = controllers.settings(kind, own, given)
    return ControllerSetup(
        node=config_from(ControllerNode, _own(ControllerNode, values)), kind=kind,
        settings=settings, ranges=ranges.ranges_from(values, node_specs.controller_channels(
            kind.name, settings.values)),
        monitor=config_from(MonitorConfig, {k: v for k, v in values.items()
                                            if k.startswith(MONITOR_PREFIX)}))


# ------------------------------------------------------------------------------- reference
@dataclass(frozen=True)
class ReferenceSetup:
    node: ReferenceNode
    reference: Reference


def reference_setup(values: Mapping[str, Any]) -> ReferenceSetup:
    """reference_node's settings (its own and the channel schedules)."""
    try:
        reference = reference_from_params(values)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    known = set(names_of(ReferenceNode)) | {s.name for s in channel_specs(reference)}
    for name in values:
        if name not in known and not node_specs.is_ros_own(name) \
                and name.split('.')[0] not in ('setpoint', 'disturbance'):
            raise ConfigError(unknown_reason(name, known))
    return ReferenceSetup(config_from(ReferenceNode, _own(ReferenceNode, values)), reference)


# -------------------------------------------------------------------------------- scenario
def check_sections(sections: Mapping[str, Any], where: str = '') -> None:
    """Section names of a scenario: the nodes, ``harness`` and ``/**`` (a misspelt one is
    refused with the nearest name)."""
    for name in sections:
        if name not in SECTIONS:
            raise ConfigError(f'{where}{unknown_reason(name, SECTIONS, "section")}')


@dataclass
class Built:
    """The core objects of one scenario (and the settings they were built from)."""

    plant: Plant
    controller: Controller
    reference: Reference
    noise: MeasurementNoise
    plant_setup: PlantSetup
    controller_setup: ControllerSetup

    @property
    def sample_time(self) -> float:
        return self.plant_setup.node.sample_time

    def guards(self) -> Guards:
        """What the nodes would refuse on their inputs (``range.*``, the fail-safe output)."""
        values = self.controller_setup.settings.values
        n = len(self.controller.input_names)
        fail_safe = values.get('fail_safe_output', 0.0)
        if not isinstance(fail_safe, (list, tuple)):
            fail_safe = [fail_safe] * n
        return Guards(controller=self.controller_setup.ranges, plant=self.plant_setup.ranges,
                      fail_safe_output=tuple(float(v) for v in fail_safe)[:n] or (0.0,) * n,
                      hold=values.get('fail_safe', 'hold') != 'output')

    def controller_values(self) -> dict[str, Any]:
        """The controller's parameter values as controller_node holds them after the run: the
        settings (derived gains included) updated by what the controller produced."""
        values = self.controller_setup.values()
        results = self.controller_setup.kind.results
        if results is not None:
            values.update(results(self.controller))
        return values


def node_values(sections: Mapping[str, Mapping[str, Any]], node: str) -> dict[str, Any]:
    """What ``node`` takes from a scenario: its own section, and the entries of ``/**`` that it
    declares (``/**`` may hold parameters of other nodes; a name no node declares is refused)."""
    wildcard = sections.get(params_file.WILDCARD, {})
    own = dict(sections.get(node, {}))
    for name in wildcard:
        if not node_specs.declared_anywhere(name):
            raise ConfigError(f'{params_file.WILDCARD}.'
                              + unknown_reason(name, node_specs.all_names()))
    probe = {**wildcard, **own}
    if node == 'plant':
        known = {s.name for s in node_specs.plant_specs(node_specs.kind_of('plant', probe))}
    elif node == 'controller':
        known = {s.name for s in node_specs.controller_specs(
            node_specs.kind_of('controller', probe), probe)}
    else:
        known = set(names_of(ReferenceNode))
        known |= {k for k in wildcard if k.split('.')[0] in ('setpoint', 'disturbance')}
    return {**{k: v for k, v in wildcard.items() if k in known}, **own}


def _in_section(node: str, error: ConfigError) -> ConfigError:
    return ConfigError(f'{node}.{error}')


def validate(sections: Mapping[str, Mapping[str, Any]],
             nodes: Iterable[str] = node_specs.NODES) -> tuple[PlantSetup, ControllerSetup]:
    """Check a scenario as its nodes would (each section, ``/**``), and that the controller
    samples at plant ticks; the plant's and controller's settings. ``ConfigError`` prefixed
    with the section (``controller.kpp: unknown parameter; did you mean kp?``)."""
    check_sections(sections)
    setups: dict[str, Any] = {}
    controller = node_values(sections, 'controller') if 'controller' in sections else None
    for node, setup in (('plant', lambda v: plant_setup(v, controller)),
                        ('controller', controller_setup), ('reference', reference_setup)):
        try:
            setups[node] = setup(node_values(sections, node))
        except ConfigError as exc:
            if node in sections or node in nodes:
                raise _in_section(node, exc) from None
            setups[node] = None
    plant, control = setups['plant'], setups['controller']
    if plant is not None and control is not None:
        reason = sample_time_reason(plant.node.sample_time, control.settings.values['sample_time'])
        if reason:
            raise _in_section('controller', ConfigError(reason))
    return plant, control


def typed(sections: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """``sections`` with every node value converted to its parameter's type as the node does
    (an integer given for a float parameter becomes a float), so a written file means the same
    to any ROS 2 tool; call it on validated sections."""
    out = {name: dict(values) for name, values in sections.items()}
    for node in node_specs.NODES:
        values = out.get(node)
        if not values:
            continue
        probe = node_values(sections, node)
        if node == 'plant':
            specs = node_specs.plant_specs(node_specs.kind_of('plant', probe))
        elif node == 'controller':
            specs = node_specs.controller_specs(node_specs.kind_of('controller', probe), probe)
        else:
            specs = specs_of(ReferenceNode) + channel_specs(reference_setup(probe).reference)
        by_name = {s.name: s for s in specs}
        out[node] = {k: coerce(by_name[k], v) if k in by_name else v for k, v in values.items()}
    return out


def build(sections: Mapping[str, Mapping[str, Any]]) -> Built:
    """Plant, controller, reference and noise from a scenario's sections."""
    setup, control = validate(sections)
    plant = setup.build_plant()
    return Built(plant=plant, controller=control.build_controller(),
                 reference=reference_setup(node_values(sections, 'reference')).reference,
                 noise=setup.build_noise(len(plant.output_names)), plant_setup=setup,
                 controller_setup=control)


def sections_of(scenario: str | Path | Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """The sections of a scenario given as a file path or already read."""
    if isinstance(scenario, Mapping):
        return {name: dict(values) for name, values in scenario.items()}
    return params_file.read(scenario)


def duration_of(sections: Mapping[str, Mapping[str, Any]], duration: float | None) -> float:
    if duration is None:
        duration = sections.get(HARNESS, {}).get('duration')
        if duration is None:
            raise ConfigError('duration: not given and the file has no harness.duration')
    return float(duration)


def run(built: Built, duration: float) -> Trace:
    """Run built objects through ``core/loop.py`` for ``duration`` simulated seconds."""
    return run_loop(built.plant, built.controller, built.reference,
                    sample_time=built.sample_time, duration=duration, noise=built.noise.sample_floats,
                    guards=built.guards())


def run_in_process(scenario: str | Path | Mapping[str, Mapping[str, Any]],
                   duration: float | None = None) -> Trace:
    """Run a scenario through ``core/loop.py`` (no ROS); ``duration`` [s] defaults to the
    file's ``harness.duration``."""
    sections = sections_of(scenario)
    return run(build(sections), duration_of(sections, duration))
