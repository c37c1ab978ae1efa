"""Scenario files: one standard ROS 2 parameters file that is also a runnable experiment.

A section per node (``plant``, ``controller``, ``reference``, optionally ``/**``) and a
``harness`` section (``duration`` [s], ``clock_mode``, ``real_time_factor``, ``nodes``, ...)
read only by the harness. Every node section is validated as the node validates it, and
``--set NODE.PARAM=VALUE`` values are typed as YAML. Layout and example: docs/harness.md.
"""
from __future__ import annotations

import copy
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tank_control.core import loop, node_specs, params_file, ros_yaml
from tank_control.core import scenario as core_scenario
from tank_control.core.node_specs import CLOCK_MODES, NODES, RTF_TINY
from tank_control.core.params import ConfigError, config_from, param, specs_of, unknown_reason
from tank_control.core.scenario import HARNESS

ALL_NODES = params_file.WILDCARD
#: ``harness.on_node_exit``: what a node that exits during a run does to it (docs/harness.md).
ON_NODE_EXIT = ('abort', 'restart')
_PARAM_NAME = re.compile(r'^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$')


class ScenarioError(ConfigError):
    """A scenario file or override that cannot be used; the message is one line."""


@dataclass(frozen=True)
class HarnessConfig:
    """The ``harness`` section."""

    duration: float = param(60.0, 'length of the run in simulated seconds', unit='s', min=1e-9,
                            max=1e7)
    clock_mode: str = param('lockstep', 'how the plant advances time', choices=CLOCK_MODES)
    real_time_factor: float = param(0.0, 'sim/lockstep pacing: simulated seconds per wall second '
                                    '(0 = as fast as possible; sim mode needs > 0; a '
                                    f'non-zero factor is at least {RTF_TINY:g})', min=0.0,
                                    max=1e6, tiny=RTF_TINY)
    nodes: tuple[str, ...] = param(NODES, 'node processes to start', choices=NODES)
    external_nodes: tuple[str, ...] = param((), 'nodes of the loop that the user runs (any '
                                            'program, named as its role, answering the lockstep '
                                            'protocol of docs/nodes.md): the harness does not '
                                            'start them, waits for their endpoints and records '
                                            'them (docs/harness.md, "External nodes")',
                                            choices=NODES)
    external_wait: float = param(30.0, 'wall seconds the harness waits for the external nodes\' '
                                 'endpoints to match before it gives up', unit='s', min=1.0,
                                 max=3600.0)
    startup_timeout: float = param(60.0, 'wall seconds allowed for the graph to come up',
                                   unit='s', min=1.0, max=3600.0)
    stall_timeout: float = param(30.0, 'wall seconds without simulated-time progress before the '
                                 'run is declared stalled', unit='s', min=1.0, max=3600.0)
    discovery_time: float = param(4.0, 'wall seconds (from the recorder joining) the harness '
                                  'looks for another graph on its ROS_DOMAIN_ID before it starts '
                                  'a node (DDS discovers a running participant within one 3 s '
                                  'announcement period on a loaded host); not waited for when '
                                  'nobody was on the domain (docs/harness.md, step 2)',
                                  unit='s', min=0.0, max=60.0)
    on_node_exit: str = param('abort', 'what a node process that exits during the run does to '
                              'it: abort ends the run (exit code 1); restart starts the node '
                              'again with its parameters and the run goes on (not the plant, '
                              'whose clock and state are the run; at most max_restarts times '
                              'per node)', choices=ON_NODE_EXIT)
    max_restarts: int = param(3, 'on_node_exit restart: restarts of one node in a run; its next '
                              'exit ends the run', min=0, max=100)
    title: str = param('', 'one-line description shown in tables and plots')
    claim: str = param('', 'the documented claim this scenario reproduces (for docs)')

    def reason(self) -> str | None:
        if not self.nodes:
            return 'nodes: empty; allowed a list of ' + ', '.join(NODES)
        stray = [n for n in self.external_nodes if n not in self.nodes]
        if stray:
            return (f'external_nodes: {stray[0]!r} is not one of nodes ({", ".join(self.nodes)})'
                    '; allowed nodes of the loop')
        if len(set(self.external_nodes)) == len(self.nodes):
            return ('external_nodes: every node of the loop is external; allowed at most '
                    f'{len(self.nodes) - 1} of nodes ({", ".join(self.nodes)})')
        if self.clock_mode == 'sim' and self.real_time_factor <= 0:
            return (f'real_time_factor: {self.real_time_factor:g} with clock_mode sim; allowed '
                    '(0, 1e6] (sim paces the clock on wall time)')
        return None

    @property
    def started(self) -> tuple[str, ...]:
        """The nodes the harness starts: ``nodes`` without ``external_nodes``."""
        return tuple(n for n in self.nodes if n not in self.external_nodes)


@dataclass
class Scenario:
    """A loaded scenario: flat parameters per section, plus where it came from."""

    path: Path
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)
    overrides: tuple[str, ...] = ()
    """The ``NODE.PARAM=VALUE`` items applied (``--set``), as given."""

    @property
    def name(self) -> str:
        return self.path.stem

    def params(self, node: str) -> dict[str, Any]:
        """Parameters a node receives from the file: the ``/**`` section overlaid by its own."""
        return params_file.node_values(self.sections, node)

    @property
    def harness(self) -> HarnessConfig:
        return config_from(HarnessConfig, self.sections.get(HARNESS, {}))

    def with_set(self, section: str, name: str, value: Any) -> Scenario:
        """A copy with one parameter changed."""
        sections = copy.deepcopy(self.sections)
        sections.setdefault(section, {})[name] = params_file.check_value(f'{section}.{name}', value)
        return Scenario(self.path, sections, self.overrides)


def parse_value(text: str) -> Any:
    """A command-line value typed as YAML (``2.5`` float, ``1e-3`` float, ``mdp`` str)."""
    try:
        return ros_yaml.load(text) if text.strip() else ''
    except yaml.YAMLError as exc:
        raise ScenarioError(f'value {text!r} is not valid YAML: {str(exc).splitlines()[0]}') from None


def load_scenario(path: str | Path, overrides: Sequence[str] = (), check_nodes: bool = True
                  ) -> Scenario:
    """Read a scenario file, apply ``NODE.PARAM=VALUE`` overrides and validate every section
    (``check_nodes=False``: the harness section only, for runs of other node programs than this
    package's, such as test stand-ins).

    Raises ``ScenarioError`` with a one-line reason naming the file and the entry.
    """
    path = Path(path)
    try:
        scenario = Scenario(path, params_file.read(path))
        for item in overrides:
            section, name, value = parse_override(item)
            scenario = scenario.with_set(section, name, value)
        scenario = Scenario(path, scenario.sections, tuple(overrides))
    except ConfigError as exc:
        raise ScenarioError(str(exc)) from None
    return validate(scenario, check_nodes)


def parse_override(item: str) -> tuple[str, str, Any]:
    """``controller.tuning.rule=mdp`` → (``controller``, ``tuning.rule``, ``'mdp'``)."""
    key, sep, text = item.partition('=')
    section, dot, name = key.strip().partition('.')
    if not sep or not dot or not name:
        raise ScenarioError(f'--set {item!r}: expected NODE.PARAM=VALUE')
    if section not in (*NODES, HARNESS):
        raise ScenarioError(f'--set {item!r}: ' + unknown_reason(section, (*NODES, HARNESS),
                                                                 'node'))
    if not _PARAM_NAME.match(name):
        raise ScenarioError(f'--set {item!r}: {name!r} is not a parameter name')
    value = parse_value(text)
    if isinstance(value, dict):
        raise ScenarioError(f'--set {item!r}: a map is not a parameter value; set its entries')
    return section, name, value


def validate(scenario: Scenario, check_nodes: bool = True) -> Scenario:
    """Every section as its node (or the harness) would check it, and the relations between
    them (the nodes to start have sections; the controller samples at plant ticks); with
    ``check_nodes=False`` the harness section only."""
    where = f'{scenario.path}: '
    try:
        core_scenario.check_sections(scenario.sections)
        try:
            config = scenario.harness
        except ConfigError as exc:
            raise ConfigError(f'harness.{exc}') from None
        # an external node's section (if any) is its own program's: not checked, passed on
        ours = {name: values for name, values in scenario.sections.items()
                if name not in config.external_nodes}
        if check_nodes:
            core_scenario.validate(ours, config.started)
        for node in config.started:
            if node in ('plant', 'controller') and node not in scenario.sections:
                raise ConfigError(f'harness.nodes: {node!r} has no section in the file')
        if not check_nodes:
            return scenario
        if {'plant', 'controller', 'reference'} <= set(config.started):
            check_wiring(scenario.sections)
        typed = {**scenario.sections, **core_scenario.typed(ours)}
        return Scenario(scenario.path, typed, scenario.overrides)
    except ConfigError as exc:
        raise ScenarioError(where + str(exc)) from None


def check_wiring(sections: dict[str, dict[str, Any]]) -> None:
    """The channels of plant, controller and reference connect (the check the in-process loop
    makes before its first tick, ``core.loop.check_wiring``), so a ROS run with a misnamed
    channel is refused before any node starts rather than stalling at tick 0."""
    built = core_scenario.build(sections)
    try:
        loop.check_wiring(built.plant, built.controller, built.reference)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def run_value(scenario: Scenario, section: str, name: str) -> Any:
    """The value ``section`` runs ``name`` with: the file's (overrides applied), else the
    declared default (the plant or controller kind's, the reference's, the harness's).
    ``ConfigError`` with the nearest known name for a name the section does not declare."""
    values = (scenario.sections.get(HARNESS, {}) if section == HARNESS
              else scenario.params(section))
    if name in values:
        return values[name]
    if section == HARNESS:
        specs = specs_of(HarnessConfig)
    elif section == 'plant':
        specs = node_specs.plant_specs(node_specs.kind_of('plant', scenario.params('plant')))
    elif section == 'controller':
        stated = scenario.params('controller')
        specs = node_specs.controller_specs(node_specs.kind_of('controller', stated), stated)
    else:
        specs = specs_of(node_specs.ReferenceNode)
    for spec in specs:
        if spec.name == name:
            return spec.default
    raise ConfigError(f'{section}.' + unknown_reason(name, [s.name for s in specs]))


def effective_harness(scenario: Scenario, mode: str | None = None, rtf: float | None = None,
                      duration: float | None = None) -> Scenario:
    """Apply the command-line ``--mode/--rtf/--duration`` as harness overrides and validate."""
    for name, value in (('clock_mode', mode), ('real_time_factor', rtf), ('duration', duration)):
        if value is not None:
            scenario = scenario.with_set(HARNESS, name, float(value) if name != 'clock_mode' else value)
    return validate(scenario, check_nodes=False)   # the node sections did not change


def node_parameters(scenario: Scenario) -> dict[str, dict[str, Any]]:
    """The sections written for the node processes: ``clock_mode`` for every node started,
    ``real_time_factor`` for the plant (the clock master)."""
    config = scenario.harness
    out = {name: dict(values) for name, values in scenario.sections.items() if name != HARNESS}
    for node in config.nodes:                     # every node samples in the same clock mode
        if node in config.started or node in out:  # an external node: only if it has a section
            out.setdefault(node, {})['clock_mode'] = config.clock_mode
    plant = out.setdefault('plant', {})
    plant['clock_mode'] = config.clock_mode
    plant['real_time_factor'] = float(config.real_time_factor)
    return out


def write_params_file(scenario: Scenario, path: str | Path) -> Path:
    """Write the merged scenario (overrides applied, clock settings on the nodes) as a standard
    ROS 2 parameters file; the harness section is kept so the file is re-runnable."""
    sections = node_parameters(scenario)
    harness = dict(scenario.sections.get(HARNESS, {}))
    config = scenario.harness
    harness.update(clock_mode=config.clock_mode, real_time_factor=float(config.real_time_factor),
                   duration=float(config.duration))
    sections[HARNESS] = harness
    return params_file.write(sections, path)


def shipped_config_dir() -> Path:
    """The shipped scenarios: ``config/`` of this checkout, else the installed share dir."""
    here = Path(__file__).resolve().parents[2] / 'config'
    if here.is_dir():
        return here
    return Path(sys.prefix) / 'share' / 'tank_control' / 'config'


def list_scenarios(directory: str | Path) -> list[tuple[Path, str]]:
    """Every scenario and study file under ``directory`` (recursively; a folder's files before
    its sub-folders', sorted by name) with its title:
    ``harness.title`` of a scenario, ``study.title`` of a study, else the first line of the
    file's leading comment; a file that does not parse gets ``(not valid YAML: …)``."""
    out = []
    root = Path(directory)
    for path in sorted(root.rglob('*.yaml'), key=lambda p: (len(p.relative_to(root).parts), p)):
        text = path.read_text(errors='replace')
        try:
            data = yaml.safe_load(text) or {}
        except yaml.YAMLError as exc:
            out.append((path, f'(not valid YAML: {str(exc).splitlines()[0]})'))
            continue
        title = ''
        if isinstance(data, dict):
            for key, inner in (('study', None), (HARNESS, 'ros__parameters')):
                section = data.get(key)
                if isinstance(section, dict) and inner:
                    section = section.get(inner)
                if isinstance(section, dict) and section.get('title'):
                    title = str(section['title'])
                    break
        if not title:
            comments = [line.lstrip('#').strip() for line in text.splitlines()
                        if line.startswith('#')]
            title = comments[0] if comments else ''
        out.append((path, title))
    return out
