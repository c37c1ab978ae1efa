"""Controller kind ``pid``: the SISO 2-DOF PID of [Viteckova] eq. 19 with limits, anti-windup, tuning,
and the robustness of the running loop on the ``tuning.*`` model (``robustness.*``,
``sampling.warning``)."""
from __future__ import annotations

from typing import Any

from tank_control.core.analysis.linear import LinearController, pid_controller
from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, LoopWatch, Settings
from tank_control.core.control.pid import PidConfig, PidController

_build_pid = base.siso_build(PidController)


def build(settings: Settings) -> PidController:
    controller = _build_pid(settings)
    base.attached(controller).loop_watch = LoopWatch(base.tuning_model(settings.values),
                                                     settings.robustness.ms_max)
    return controller


def update(controller: PidController, settings: Settings, changed: frozenset[str]) -> bool:
    """:func:`base.siso_update` (gains bumplessly, then the mode); the model of the analysis."""
    base.siso_update(controller, settings, changed)
    watch = base.attached(controller).loop_watch
    watch.model, watch.ms_max = base.tuning_model(settings.values), settings.robustness.ms_max
    return True


def reason(settings: Settings) -> str | None:
    """SISO relations, then the robustness guard on the ``tuning.*`` model."""
    return base.siso_reason(settings) or base.guard_reason(
        settings, base.tuning_model(settings.values), settings.config)


def linear(settings: Settings) -> LinearController:
    """The implemented 2-DOF PID's discrete transfer function, and the ``tuning.*`` model."""
    return pid_controller(settings.config, (('tuning.*', base.tuning_model(settings.values)),))


def results(controller: PidController) -> dict[str, Any]:
    """``robustness.*`` of the running loop and [DeadTimeNotes]'s sampling advice on the model."""
    watch = base.attached(controller).loop_watch
    config = controller.pid.config
    return {**watch.values(config), **watch.sampling(config.sample_time)}


KIND = ControllerKind(
    name='pid',
    description='SISO 2-DOF PID ([Viteckova] eq. 19) with filter, limits, anti-windup, tuning rules',
    config=PidConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start(),
            base.TUNING, base.ROBUSTNESS, base.ROBUSTNESS_RESULTS, base.SAMPLING_RESULTS),
    build=build, update=update, derive=base.tuned_gains, reason=reason, results=results,
    gains=('kp', 'ti', 'td', 'b', 'c', 'n'), input_limits=base.scalar_limits, linear=linear,
)
