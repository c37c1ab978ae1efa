"""Controller kind ``pid``: the SISO 2-DOF PID of 000 eq. 19 with limits, anti-windup, tuning."""
from __future__ import annotations

from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.control.pid import PidConfig, PidController


def build(settings: Settings) -> PidController:
    controller = PidController(settings.config, output_name=settings.channels.output_names[0],
                               input_name=settings.channels.input_names[0])
    if settings.mode.mode == 'manual':
        controller.pid.set_manual(float(settings.mode.manual_output))
    return controller


def update(controller: PidController, settings: Settings, changed: frozenset[str]) -> bool:
    """Gains and limits through ``Pid2Dof.set_gains`` (the integral absorbs the change), then
    the mode (manual output / bumpless return to auto)."""
    pid = controller.pid
    base.set_changed_gains(pid, settings.config)
    base.apply_mode(pid, pid.mode, settings, changed)
    return True


KIND = ControllerKind(
    name='pid',
    description='SISO 2-DOF PID (000 eq. 19) with filter, limits, anti-windup, tuning rules',
    config=PidConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start(),
            base.TUNING),
    build=build, update=update, derive=base.tuned_gains, reason=base.siso_reason,
    gains=('kp', 'ti', 'td', 'b', 'c', 'n'), input_limits=base.scalar_limits,
)
