"""Controller kind ``lead_lag``: the lead-lag compensator K·(Td·s + 1)/(α·Td·s + 1)·(1 + 1/(Ti·s))
with [Ikonen]'s frequency-domain design (``tuning.rule: frequency_002``) from a process model, and
the robustness of the running loop on that model (``robustness.*``, the ``ms_max`` guard)."""
from __future__ import annotations

from typing import Any

from tank_control.core.analysis.linear import LinearController
from tank_control.core.analysis.robustness import LoopReport, response_report
from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, LoopWatch, Settings
from tank_control.core.control.lead_lag import (LeadLagConfig, LeadLagController, LeadLagTuning,
                                                design, discrete_response)
from tank_control.core.params import config_from
from tank_control.core.tuning.model import ProcessModel

TUNING = base.group('tuning', LeadLagTuning)
GUARDED = ('lead_lag.kp', 'lead_lag.td', 'lead_lag.alpha', 'lead_lag.ti', 'sample_time',
           'direct_action', 'robustness.ms_max')
"""Parameters whose change the robustness guard checks."""


def process_model(values: base.Values) -> ProcessModel | None:
    """The process model of the ``tuning.*`` group (``tuning.model`` with its gain, time
    constants and dead time), or None when it is incomplete."""
    t1, t2 = float(values['tuning.time_constant']), float(values['tuning.time_constant2'])
    kind = str(values['tuning.model'])
    model = ProcessModel(kind, float(values['tuning.gain']), float(values['tuning.dead_time']),
                         max(t1, t2) if kind != 'ipdt' else 0.0,
                         min(t1, t2) if kind == 'sopdt' else 0.0)
    return None if model.reason() is not None else model


def loop_report(model: ProcessModel, config: LeadLagConfig) -> LoopReport:
    """Robustness of the implemented discrete lead-lag (:func:`discrete_response`, one degree
    of freedom) on the exact ZOH ``model`` at ``config.sample_time``."""
    return response_report(model, discrete_response(config.kp, config.td, config.alpha,
                                                    config.ti, config.sample_time))


def _key(config: LeadLagConfig) -> tuple[float, ...]:
    return (config.kp, config.td, config.alpha, config.ti, config.sample_time)


def _gains(config: LeadLagConfig) -> str:
    return (f'lead_lag.kp {config.kp:.4g}, td {config.td:.4g} s, alpha {config.alpha:.3g}, '
            f'ti {config.ti:.4g} s')


_build = base.siso_build(LeadLagController)


def build(settings: Settings) -> LeadLagController:
    controller = _build(settings)
    base.attached(controller).loop_watch = LoopWatch(process_model(settings.values),
                                                     settings.robustness.ms_max, loop_report, _key)
    return controller


def update(controller: LeadLagController, settings: Settings, changed: frozenset[str]) -> bool:
    """:func:`base.siso_update`; the model of the analysis."""
    base.siso_update(controller, settings, changed)
    watch = base.attached(controller).loop_watch
    watch.model, watch.ms_max = process_model(settings.values), settings.robustness.ms_max
    return True


def reason(settings: Settings) -> str | None:
    """SISO relations, then the robustness guard on the ``tuning.*`` model."""
    return base.siso_reason(settings) or base.guard_reason(
        settings, process_model(settings.values), settings.config, loop_report, GUARDED, _gains)


def results(controller: LeadLagController) -> dict[str, Any]:
    """``robustness.*`` of the running loop."""
    return base.attached(controller).loop_watch.values(controller.lead_lag.config)


def linear(settings: Settings) -> LinearController:
    """The implemented discrete lead-lag (one degree of freedom; gain magnitude), and the
    ``tuning.*`` model."""
    c = settings.config
    return LinearController(
        discrete_response(abs(c.kp), c.td, c.alpha, c.ti, c.sample_time),
        f'lead-lag kp {abs(c.kp):.4g}, td {c.td:.4g} s, alpha {c.alpha:.3g}, ti {c.ti:.4g} s',
        models=tuple(('tuning.*', m) for m in (process_model(settings.values),)
                     if m is not None))


def derive(values: base.Values) -> dict[str, float]:
    """``lead_lag.kp``, ``lead_lag.td``, ``lead_lag.ti`` from [Ikonen]'s design ([Ikonen] §1.1–1.4) of
    ``tuning.kind`` on ``tuning.model`` with ``lead_lag.alpha``; none without a rule."""
    if values['tuning.rule'] == 'none':
        return {}
    tuning = config_from(LeadLagTuning, {s.name: values[s.name] for s in TUNING.specs()})
    return design(tuning, float(values['lead_lag.alpha'])).values()


KIND = ControllerKind(
    name='lead_lag',
    description='lead-lag compensator K (Td s+1)/(alpha Td s+1) (1 + 1/(Ti s)) with limits, '
                "anti-windup and [Ikonen]'s frequency-domain design ([Ikonen] §1)",
    config=LeadLagConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start(),
            TUNING, base.ROBUSTNESS, base.ROBUSTNESS_RESULTS),
    build=build, update=update, derive=derive, reason=reason, results=results,
    gains=('lead_lag.kp', 'lead_lag.td', 'lead_lag.alpha', 'lead_lag.ti'),
    input_limits=base.scalar_limits, linear=linear,
)
