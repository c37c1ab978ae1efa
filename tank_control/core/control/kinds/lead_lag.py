"""Controller kind ``lead_lag``: the lead-lag compensator K·(Td·s + 1)/(α·Td·s + 1)·(1 + 1/(Ti·s))
with 002's frequency-domain design (``tuning.rule: frequency_002``) from a process model."""
from __future__ import annotations

from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.control.lead_lag import (LeadLagConfig, LeadLagController, LeadLagTuning,
                                                design)
from tank_control.core.params import config_from

TUNING = base.group('tuning', LeadLagTuning)


def derive(values: base.Values) -> dict[str, float]:
    """``lead_lag.kp``, ``lead_lag.td``, ``lead_lag.ti`` from 002's design (002 §1.1–1.4) of
    ``tuning.kind`` on ``tuning.model`` with ``lead_lag.alpha``; none without a rule."""
    if values['tuning.rule'] == 'none':
        return {}
    tuning = config_from(LeadLagTuning, {s.name: values[s.name] for s in TUNING.specs()})
    return design(tuning, float(values['lead_lag.alpha'])).values()


def build(settings: Settings) -> LeadLagController:
    controller = LeadLagController(settings.config,
                                   output_name=settings.channels.output_names[0],
                                   input_name=settings.channels.input_names[0])
    if settings.mode.mode == 'manual':
        controller.lead_lag.set_manual(float(settings.mode.manual_output))
    return controller


def update(controller: LeadLagController, settings: Settings, changed: frozenset[str]) -> bool:
    """Settings through ``LeadLag.set_gains`` (the integral absorbs the change), then the mode."""
    law = controller.lead_lag
    base.set_changed_gains(law, settings.config)
    base.apply_mode(law, law.mode, settings, changed)
    return True


KIND = ControllerKind(
    name='lead_lag',
    description='lead-lag compensator K (Td s+1)/(alpha Td s+1) (1 + 1/(Ti s)) with limits, '
                "anti-windup and 002's frequency-domain design (002 §1)",
    config=LeadLagConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start(),
            TUNING),
    build=build, update=update, derive=derive, reason=base.siso_reason,
    gains=('lead_lag.kp', 'lead_lag.td', 'lead_lag.alpha', 'lead_lag.ti'),
    input_limits=base.scalar_limits,
)
