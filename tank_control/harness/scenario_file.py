"""Scenario files: one standard ROS 2 parameters file that is also a runnable experiment.

A scenario has a section per node name (``plant``, ``controller``, ``reference``)
in the ``ros2 run ... --ros-args --params-file`` format, plus a ``harness``
section read only by the scenario harness::

    plant:
      ros__parameters: {plant: ipdt, gain: 0.05, dead_time: 5.0, sample_time: 0.1}
    controller:
      ros__parameters: {controller: pid, kp: 3.14, ti: 18.66}
    reference:
      ros__parameters: {...}
    harness:
      ros__parameters:
        duration: 100.0            # simulated seconds
        clock_mode: lockstep       # lockstep | sim | wall
        real_time_factor: 0.0      # 0 = as fast as possible (lockstep only)
        nodes: [plant, controller, reference]

Nested maps are the usual ROS 2 way of writing dotted names (``tuning: {rule: mdp}``
is the parameter ``tuning.rule``); this module keeps parameters flat, by dotted
name, and writes them back nested. A ``/**`` section (parameters for every node)
is kept as is.

``--set NODE.PARAM=VALUE`` overrides are typed as YAML (``kp=2.5`` is a float,
``rule=mdp`` a string, ``steps=[0.0, 1.0]`` a list); an integer given for a
parameter the file holds as a float stays a float, as ROS 2 would otherwise
refuse it.
"""
from __future__ import annotations

import copy
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tank_control.core import ros_yaml
from tank_control.core.params import ParamSpec, check_all, defaults

NODE_NAMES = ('plant', 'controller', 'reference')
HARNESS = 'harness'
ALL_NODES = '/**'
CLOCK_MODES = ('lockstep', 'sim', 'wall')

HARNESS_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec('duration', 60.0, 'length of the run in simulated seconds [s]', min=1e-9, max=1e7),
    ParamSpec('clock_mode', 'lockstep', 'how the plant advances time', choices=CLOCK_MODES),
    ParamSpec('real_time_factor', 0.0,
              'sim/lockstep pacing: simulated seconds per wall second (0 = as fast as possible; '
              'sim mode needs > 0)', min=0.0, max=1e6),
    ParamSpec('nodes', list(NODE_NAMES), 'node processes to start', choices=NODE_NAMES),
    ParamSpec('startup_timeout', 60.0, 'wall seconds allowed for the graph to come up [s]',
              min=1.0, max=3600.0),
    ParamSpec('stall_timeout', 30.0,
              'wall seconds without simulated-time progress before the run is declared stalled [s]',
              min=1.0, max=3600.0),
    ParamSpec('title', '', 'one-line description shown in tables and plots'),
    ParamSpec('claim', '', 'the documented claim this scenario reproduces (for docs)'),
)

_PARAM_NAME = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$')


class ScenarioError(ValueError):
    """A scenario file or override that cannot be used; the message is one line."""


def parse_value(text: str) -> Any:
    """A command-line value typed as YAML (``2.5`` float, ``1e-3`` float, ``mdp`` str)."""
    try:
        return ros_yaml.load(text) if text.strip() else ''
    except yaml.YAMLError as exc:
        raise ScenarioError(f'value {text!r} is not valid YAML: {str(exc).splitlines()[0]}') from None


@dataclass
class HarnessConfig:
    """The ``harness`` section, typed (see ``HARNESS_SPECS`` for meaning and ranges)."""

    duration: float = 60.0
    clock_mode: str = 'lockstep'
    real_time_factor: float = 0.0
    nodes: tuple[str, ...] = NODE_NAMES
    startup_timeout: float = 60.0
    stall_timeout: float = 30.0
    title: str = ''
    claim: str = ''


@dataclass
class Scenario:
    """A loaded scenario: flat parameters per section, plus where it came from."""

    path: Path
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.path.stem

    def params(self, node: str) -> dict[str, Any]:
        """Parameters a node receives: the ``/**`` section overlaid by its own."""
        merged = dict(self.sections.get(ALL_NODES, {}))
        merged.update(self.sections.get(node, {}))
        return merged

    @property
    def harness(self) -> HarnessConfig:
        values = defaults(HARNESS_SPECS)
        values.update(self.sections.get(HARNESS, {}))
        values['nodes'] = tuple(values['nodes'])
        return HarnessConfig(**{k: values[k] for k in HarnessConfig.__dataclass_fields__})

    def with_set(self, section: str, name: str, value: Any) -> Scenario:
        """A copy with one parameter changed (ints stay floats where the file had a float)."""
        sections = copy.deepcopy(self.sections)
        target = sections.setdefault(section, {})
        old = target.get(name)
        if isinstance(old, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        target[name] = _check_value(f'{section}.{name}', value)
        return Scenario(self.path, sections)


def load_scenario(path: str | Path, overrides: Sequence[str] = ()) -> Scenario:
    """Read a scenario file, apply ``NODE.PARAM=VALUE`` overrides, validate the harness section.

    Raises ``ScenarioError`` with a one-line reason naming the file and the entry.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ScenarioError(f'{path}: cannot read ({exc.strerror})') from None
    try:
        document = ros_yaml.load(text)
    except yaml.YAMLError as exc:
        raise ScenarioError(f'{path}: not valid YAML: {str(exc).splitlines()[0]}') from None
    scenario = Scenario(path, _sections(path, document))
    for item in overrides:
        section, name, value = parse_override(item)
        scenario = scenario.with_set(section, name, value)
    return validate(scenario)


def parse_override(item: str) -> tuple[str, str, Any]:
    """``controller.tuning.rule=mdp`` → (``controller``, ``tuning.rule``, ``'mdp'``)."""
    key, sep, text = item.partition('=')
    section, dot, name = key.strip().partition('.')
    if not sep or not dot or not name:
        raise ScenarioError(f'--set {item!r}: expected NODE.PARAM=VALUE')
    if section not in (*NODE_NAMES, HARNESS):
        raise ScenarioError(f'--set {item!r}: node {section!r} unknown; allowed '
                            + ', '.join((*NODE_NAMES, HARNESS)))
    if not _PARAM_NAME.match(name):
        raise ScenarioError(f'--set {item!r}: {name!r} is not a parameter name')
    value = parse_value(text)
    if isinstance(value, dict):
        raise ScenarioError(f'--set {item!r}: a map is not a parameter value; set its entries')
    return section, name, value


def validate(scenario: Scenario) -> Scenario:
    """Check the harness section against ``HARNESS_SPECS`` and the cross-section relations."""
    where = scenario.path
    reasons = check_all(HARNESS_SPECS, scenario.sections.get(HARNESS, {}))
    if reasons:
        raise ScenarioError(f'{where}: harness.{reasons[0]}')
    config = scenario.harness
    if not config.nodes:
        raise ScenarioError(f'{where}: harness.nodes: empty; allowed a list of ' + ', '.join(NODE_NAMES))
    if config.clock_mode == 'sim' and config.real_time_factor <= 0:
        raise ScenarioError(f'{where}: harness.real_time_factor: {config.real_time_factor:g} with '
                            'clock_mode sim; allowed (0, 1e6] (sim paces the clock on wall time)')
    for node in config.nodes:
        if node in ('plant', 'controller') and node not in scenario.sections:
            raise ScenarioError(f'{where}: harness.nodes: {node!r} has no section in the file')
    return scenario


def effective_harness(scenario: Scenario, mode: str | None = None, rtf: float | None = None,
                      duration: float | None = None) -> Scenario:
    """Apply the command-line ``--mode/--rtf/--duration`` as harness overrides and validate."""
    for name, value in (('clock_mode', mode), ('real_time_factor', rtf), ('duration', duration)):
        if value is not None:
            scenario = scenario.with_set(HARNESS, name, float(value) if name != 'clock_mode' else value)
    return validate(scenario)


def node_parameters(scenario: Scenario) -> dict[str, dict[str, Any]]:
    """The parameters written for the node processes: ``clock_mode`` for every node started,
    ``real_time_factor`` for the plant (the clock master)."""
    config = scenario.harness
    out = {name: dict(values) for name, values in scenario.sections.items() if name != HARNESS}
    for node in config.nodes:                     # every node samples in the same clock mode
        out.setdefault(node, {})['clock_mode'] = config.clock_mode
    plant = out.setdefault('plant', {})
    plant['clock_mode'] = config.clock_mode
    plant['real_time_factor'] = float(config.real_time_factor)
    return out


def write_params_file(scenario: Scenario, path: str | Path) -> Path:
    """Write the merged scenario (overrides applied, clock settings on the plant) as a
    standard ROS 2 parameters file; the harness section is kept so the file is re-runnable."""
    path = Path(path)
    sections = node_parameters(scenario)
    harness = dict(scenario.sections.get(HARNESS, {}))
    harness.update(clock_mode=scenario.harness.clock_mode,
                   real_time_factor=float(scenario.harness.real_time_factor),
                   duration=float(scenario.harness.duration))
    sections[HARNESS] = harness
    document = {name: {'ros__parameters': _nest(values)} for name, values in sections.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(ros_yaml.dump(document))
    return path


def _sections(path: Path, document: Any) -> dict[str, dict[str, Any]]:
    if not isinstance(document, dict):
        raise ScenarioError(f'{path}: expected a map of node sections ({", ".join(NODE_NAMES)}, '
                            f'{HARNESS})')
    allowed = (*NODE_NAMES, HARNESS, ALL_NODES)
    sections: dict[str, dict[str, Any]] = {}
    for raw_name, body in document.items():
        name = str(raw_name)
        name = name if name == ALL_NODES else name.lstrip('/')
        if name not in allowed:
            raise ScenarioError(f'{path}: section {raw_name!r} unknown; allowed ' + ', '.join(allowed))
        if not isinstance(body, dict) or set(body) != {'ros__parameters'}:
            raise ScenarioError(f'{path}: section {name!r} must hold exactly one key, ros__parameters')
        params = body['ros__parameters'] or {}
        if not isinstance(params, dict):
            raise ScenarioError(f'{path}: {name}.ros__parameters must be a map')
        flat = ros_yaml.flatten(params)
        sections[name] = {key: _check_value(f'{path}: {name}.{key}', value)
                          for key, value in flat.items()}
    return sections


def _nest(flat: Mapping[str, Any]) -> dict[str, Any]:
    tree: dict[str, Any] = {}
    for name, value in flat.items():
        *parents, leaf = name.split('.')
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return tree


def _check_value(where: str, value: Any) -> Any:
    """ROS 2 parameter values: bool, int, float, str or a homogeneous list of one of them."""
    if isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ScenarioError(f'{where}: {value} is not finite; ROS 2 parameter files need '
                                'finite numbers (leave the parameter out for "no limit")')
        return value
    if isinstance(value, list):
        if not value:
            raise ScenarioError(f'{where}: empty list (ROS 2 cannot type it); leave it out')
        items = [_check_value(where, item) if not isinstance(item, list) else None for item in value]
        kinds = {type(item) for item in items}
        if kinds <= {int, float} and float in kinds:
            return [float(item) for item in items]   # ROS 2 lists are homogeneous
        if len(kinds) != 1 or None in items:
            raise ScenarioError(f'{where}: list mixes types; ROS 2 lists hold one type')
        return items
    raise ScenarioError(f'{where}: {value!r} is not a ROS 2 parameter value '
                        '(bool, int, float, string or a list of one of them)')
