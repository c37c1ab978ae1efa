"""The SISO loop of a scenario on its linear models (the plant's, the controller's own).

Scenario glue beside ``core/scenario.py``: it reads a scenario's sections and the controller's
parameters and asks the kinds for their linear descriptions; the analysis itself is
``core/analysis/`` (``linear.py``: what a kind says; ``robustness.py``: the margins). A loop
is analysed when both kinds describe themselves: the controller kind's ``linear(settings)``
gives its discrete transfer function, the plant kind's ``linear(config)`` its model; no kind is
named here. Its robustness is :meth:`LinearController.report` (exact dead time, the
implemented discrete loop). Used by the harness's analysis (``harness/analysis.py``,
``tank-control analyze``, ``analysis.png``, ``loop_analysis`` of metrics.json) and the
dashboard's robustness panel.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from tank_control.core import scenario as core_scenario
from tank_control.core.analysis.linear import LinearController, LinearModel
from tank_control.core.analysis.robustness import LoopReport
from tank_control.core.params import ConfigError


@dataclass(frozen=True)
class LoopCase:
    """One model a SISO loop is analysed on: ``label`` (plant / controller's model), the
    ``model``, the controller's description and the channels."""

    label: str
    model: LinearModel
    controller: LinearController
    output: str
    input: str

    def report(self) -> LoopReport:
        """The loop's :class:`LoopReport`, computed once (the case is immutable)."""
        cached = self.__dict__.get('_report')
        if cached is None:
            cached = self.controller.report(self.model)
            object.__setattr__(self, '_report', cached)
        return cached


def describe_loop(plant_values: Mapping[str, Any] | None,
                  controller_values: Mapping[str, Any]) -> tuple[list[LoopCase], str]:
    """``(cases, reason)``: the loop on the plant's model (when ``plant_values`` are given and
    the plant kind has a linear model) and on each model the controller carries; ``reason``
    one line saying why there is no case. ``ConfigError``/``ValueError`` for bad values."""
    setup = core_scenario.controller_setup(controller_values, given=())
    kind, settings = setup.kind, setup.settings
    controller = kind.linear(settings) if kind.linear is not None else None
    if controller is None:
        return [], (f'controller {kind.name}: ' + (kind.no_linear or (
            'the kind gives no linear description (ControllerKind.linear; '
            'docs/extending.md)')))
    if not settings.has('channels') or (len(settings.channels.output_names),
                                        len(settings.channels.input_names)) != (1, 1):
        return [], f'controller {kind.name}: not a SISO loop'
    out_name = settings.channels.output_names[0]
    in_name = settings.channels.input_names[0]
    cases: list[LoopCase] = []
    reason = ''
    model = None
    if plant_values is not None:
        plant = core_scenario.plant_setup(plant_values)
        model = plant.kind.linear(plant.model) if plant.kind.linear is not None else None
        if model is not None:
            cases.append(LoopCase(f'plant ({model.describe()})', model, controller, out_name,
                                  in_name))
        else:
            reason = (f'plant {plant.kind.name}: no linear model of these settings '
                      '(PlantKind.linear; docs/extending.md)')
    for source, own in controller.models:
        if own != model:
            cases.append(LoopCase(f'{source} model ({own.describe()})', own, controller,
                                  out_name, in_name))
    return cases, ('' if cases else reason or f'controller {kind.name}: no model to analyse on')


def loop_cases(sections: Mapping[str, Mapping[str, Any]],
               controller_values: Mapping[str, Any] | None = None) -> list[LoopCase]:
    """The SISO loop of a scenario on the plant's model and on the controller's own models;
    ``controller_values``: the controller's parameters after a run (final gains, identified
    model), default the file's. Empty when a kind has no linear description."""
    values = controller_values
    if values is None:
        setup = core_scenario.controller_setup(core_scenario.node_values(sections, 'controller'))
        values = setup.values()
    try:
        plant_values: Mapping[str, Any] | None = core_scenario.node_values(sections, 'plant')
        core_scenario.plant_setup(plant_values or {})
    except ConfigError:
        plant_values = None
    return describe_loop(plant_values, values)[0]
