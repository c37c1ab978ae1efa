"""Core objects from the flat parameters the nodes receive, and the in-process run.

A scenario is a standard ROS 2 parameters file::

    /**:                       # parameters for every node (optional)
      ros__parameters: {...}
    plant:
      ros__parameters: {plant: ipdt, sample_time: 0.1, gain: 0.05, dead_time: 5.0, ...}
    controller:
      ros__parameters: {controller: pid, sample_time: 0.1, kp: 3.14, ...}
    reference:
      ros__parameters: {setpoint.channels: [y], setpoint.y.value: 1.0, ...}
    harness:                   # read by the harness only (duration, clock mode, ...)
      ros__parameters: {duration: 100.0}

``read_params_file`` gives, per node name, the flat parameters that node sees
(``/**`` first, then its own section; nested maps flattened to dotted names, as
ROS 2 does). ``build_plant``, ``build_noise``, ``make_controller`` and
``reference_from_params`` turn them into the very objects ``plant_node``,
``controller_node`` and ``reference_node`` construct, so
``run_in_process(path)`` reproduces a lockstep ROS run (core/loop.py).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from tank_control.core import ros_yaml
from tank_control.core.interfaces import Controller, Plant
from tank_control.core.loop import Noise, Trace, run_loop
from tank_control.core.params import ParamSpec, check_all
from tank_control.core.plants import (NOISE_PARAMS, PLANT_KIND_SPEC, PLANT_KINDS, make_plant,
                                      plant_params)
from tank_control.core.plants.noise import MeasurementNoise
from tank_control.core.reference import Reference, reference_from_params

CLOCK_MODES = ('wall', 'sim', 'lockstep')

#: Parameters of plant_node besides the model's own (``plant_params(kind)``):
#: the kind, the tick, the measurement noise (``NOISE_PARAMS``) and the clock.
PLANT_NODE_SPECS: tuple[ParamSpec, ...] = (
    PLANT_KIND_SPEC,
    ParamSpec('sample_time', 0.1, 'plant tick: measurements are published every sample_time; '
              'in sim/lockstep tick k is at k * sample_time [s]', min=1e-4, max=3600.0,
              read_only=True),
) + NOISE_PARAMS + (
    ParamSpec('clock_mode', 'wall', 'wall: real time; sim: the plant publishes /clock at '
              'real_time_factor x real time; lockstep: /clock advances when every answer of a '
              'tick arrived', choices=CLOCK_MODES, read_only=True),
    ParamSpec('real_time_factor', 1.0, 'simulated seconds per wall second in sim/lockstep '
              '(lockstep: 0 = as fast as possible)', min=0.0, max=1e6),
    ParamSpec('lockstep.resend_period', 0.5, 'lockstep: re-send the current tick when its '
              'answers have not come within this wall time [s]', min=0.01, max=60.0),
    ParamSpec('lockstep.paused', False, 'sim and lockstep: hold the current tick (simulated '
              'time stops) until set to false; wall: hold the first tick only; lets a recorder '
              'join before tick 0'),
    ParamSpec('lockstep.wait_for_reference', True, 'lockstep: also wait for the reference '
              'disturbance message of each tick'),
    ParamSpec('diagnostics_period', 1.0, 'period of /diagnostics [wall s]', min=0.05, max=3600.0),
)


_WILDCARDS = ('/**', '/*')


def read_params_file(path: str | Path) -> dict[str, dict[str, Any]]:
    """Node name → flat parameters that node receives from the file.

    Sections may be named ``plant``, ``/plant`` or ``/**/plant``; the wildcard
    sections ``/**`` and ``/*`` apply to every node and are overridden by a
    node's own section. The result holds every named section plus ``/**``
    (the wildcard values alone). ValueError with the file name on bad input.
    """
    path = Path(path)
    try:
        document = ros_yaml.load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f'{path}: cannot read a ROS 2 params file ({exc})') from None
    if not isinstance(document, dict):
        raise ValueError(f'{path}: expected a map of node sections with ros__parameters')
    wildcard: dict[str, Any] = {}
    own: dict[str, dict[str, Any]] = {}
    for raw, body in document.items():
        if not isinstance(body, dict) or not isinstance(body.get('ros__parameters', {}), dict):
            raise ValueError(f'{path}: section {raw!r} must hold a ros__parameters map')
        flat = ros_yaml.flatten(body.get('ros__parameters') or {})
        name = str(raw)
        if name in _WILDCARDS:
            wildcard.update(flat)
            continue
        name = name.removeprefix('/**/').lstrip('/')
        own.setdefault(name, {}).update(flat)
    result = {name: {**wildcard, **values} for name, values in own.items()}
    result['/**'] = dict(wildcard)
    return result


def node_values(params: Mapping[str, Mapping[str, Any]], node: str) -> dict[str, Any]:
    """The flat parameters of ``node`` (the wildcard values if it has no section)."""
    return dict(params.get(node, params.get('/**', {})))


# ------------------------------------------------------------------------ plant

def plant_specs(kind: str) -> tuple[ParamSpec, ...]:
    """Every plant_node parameter for model ``kind``: node specs + the model's own."""
    own = plant_params(kind)
    names = {s.name for s in own}
    return tuple(s for s in PLANT_NODE_SPECS if s.name not in names) + tuple(own)


def complete_plant_values(values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` with every default filled in; ValueError with the reasons if invalid."""
    kind = str(values.get('plant', PLANT_KIND_SPEC.default))
    if kind not in PLANT_KINDS:
        raise ValueError(f'plant: {kind!r} is not a choice; allowed one of {", ".join(PLANT_KINDS)}')
    specs = plant_specs(kind)
    known = {s.name for s in specs}
    merged = {s.name: s.default for s in specs}
    merged.update({k: v for k, v in values.items() if k in known})
    reasons = check_all(specs, {k: v for k, v in values.items() if k in known})
    if reasons:
        raise ValueError('; '.join(reasons))
    return merged


def model_values(values: Mapping[str, Any]) -> dict[str, Any]:
    """The model's own parameters (those of ``plant_params(kind)``) out of plant_node values."""
    return {s.name: values[s.name] for s in plant_params(str(values['plant'])) if s.name in values}


def build_plant(values: Mapping[str, Any]) -> Plant:
    """The plant model of complete plant_node ``values`` (``make_plant(kind, model values)``)."""
    return make_plant(str(values['plant']), model_values(values))


def build_noise(values: Mapping[str, Any], output_names: tuple[str, ...]) -> MeasurementNoise:
    """The seeded measurement noise of plant_node ``values`` (one ``sample()`` per tick)."""
    return MeasurementNoise(len(output_names), values['noise_std'], seed=int(values['seed']))


# ------------------------------------------------------------------- controller

def make_controller(values: Mapping[str, Any]) -> Controller:
    """The controller of controller_node ``values`` (the registry controller_node uses;
    the node's own parameters such as ``clock_mode`` are left out)."""
    from tank_control.core.control.registry import make_controller as registry_make
    from tank_control.core.control.registry import specs_for
    # Node-level parameters (clock_mode, stale_samples, ...) are not the controller's.
    own = {spec.name for spec in specs_for(str(values.get('controller', 'pid')))}
    return registry_make({k: v for k, v in values.items() if k in own})


# --------------------------------------------------------------------- scenario

@dataclass
class Built:
    """The core objects of one scenario."""

    plant: Plant
    controller: Controller
    reference: Reference
    noise: Noise | None
    sample_time: float
    plant_values: dict[str, Any]


def build(params: Mapping[str, Mapping[str, Any]]) -> Built:
    """Plant, controller, reference and noise from node name → flat parameters."""
    plant_values = complete_plant_values(node_values(params, 'plant'))
    plant = build_plant(plant_values)
    noise_src = build_noise(plant_values, plant.output_names)
    return Built(plant=plant,
                 controller=make_controller(node_values(params, 'controller')),
                 reference=reference_from_params(node_values(params, 'reference')),
                 noise=noise_src.sample, sample_time=float(plant_values['sample_time']),
                 plant_values=plant_values)


def run_in_process(params_file: str | Path | Mapping[str, Mapping[str, Any]],
                   duration: float | None = None) -> Trace:
    """Run a scenario through ``core/loop.py`` (no ROS). ``duration`` [s] defaults to
    ``harness.duration`` of the file."""
    params = params_file if isinstance(params_file, Mapping) else read_params_file(params_file)
    if duration is None:
        duration = params.get('harness', {}).get('duration')
        if duration is None:
            raise ValueError('duration: not given and the file has no harness.duration')
    built = build(params)
    return run_loop(built.plant, built.controller, built.reference,
                    sample_time=built.sample_time, duration=float(duration), noise=built.noise)
