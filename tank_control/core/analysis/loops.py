"""The SISO PID loop of a scenario on its process models (the plant's, the controller's own).

A SISO loop is a ``pid`` or ``relay_autotune`` controller on a plant that is a process model
(``fopdt``, ``ipdt``, ``sopdt``: ``core/tuning/model.from_plant``); its robustness is
``core/analysis/robustness.loop_report`` (exact dead time, the implemented discrete loop).
Used by the harness's analysis (``harness/analysis.py``) and the dashboard's robustness panel.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from tank_control.core import scenario as core_scenario
from tank_control.core.analysis.robustness import LoopReport, loop_report
from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.relay_autotune import identified_model
from tank_control.core.control.pid import PidConfig
from tank_control.core.params import ConfigError
from tank_control.core.tuning.model import ProcessModel, from_plant

PID_KINDS = ('pid', 'relay_autotune')


@dataclass(frozen=True)
class LoopCase:
    """One model a SISO loop is analysed on: ``label`` (plant / controller's model), the
    ``model``, the PID settings (``config``: gains, filter, sample time) and the channels."""

    label: str
    model: ProcessModel
    config: PidConfig
    output: str
    input: str

    def report(self) -> LoopReport:
        return loop_report(self.model, self.config)


def loop_cases(sections: Mapping[str, Mapping[str, Any]],
               controller_values: Mapping[str, Any] | None = None) -> list[LoopCase]:
    """The SISO loop of a scenario on the plant's model and on the controller's own model;
    ``controller_values``: the controller's parameters after a run (final gains, identified
    model), default the file's. Empty for other controllers and plants."""
    values = controller_values
    if values is None:
        setup = core_scenario.controller_setup(core_scenario.node_values(sections, 'controller'))
        values = setup.values()
    kind = values.get('controller')
    if kind not in PID_KINDS:
        return []
    setup = core_scenario.controller_setup(values, given=())
    config = setup.settings.config
    if not isinstance(config, PidConfig):
        return []
    config = replace(config, kp=abs(config.kp), direct_action=False)
    out_name = setup.settings.channels.output_names[0]
    in_name = setup.settings.channels.input_names[0]
    cases = []
    try:
        plant = core_scenario.plant_setup(core_scenario.node_values(sections, 'plant'))
        model = from_plant(plant.kind.name, plant.model)
    except ConfigError:
        model = None
    if model is not None:
        cases.append(LoopCase(f'plant ({model.describe()})', model, config, out_name, in_name))
    own = (base.tuning_model(setup.settings.values) if kind == 'pid'
           else identified_model(setup.settings.values))
    if own is not None and own != model:
        source = 'tuning.*' if kind == 'pid' else 'identified'
        cases.append(LoopCase(f'{source} model ({own.describe()})', own, config, out_name,
                              in_name))
    return cases
