"""Controller kind ``pid``: the SISO 2-DOF PID of 000 eq. 19 with limits, anti-windup, tuning."""
from __future__ import annotations

from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind
from tank_control.core.control.pid import PidConfig, PidController


KIND = ControllerKind(
    name='pid',
    description='SISO 2-DOF PID (000 eq. 19) with filter, limits, anti-windup, tuning rules',
    config=PidConfig,
    groups=(base.channels(('y',), ('u',)), base.MODE, base.fail_safe(), base.warm_start(),
            base.TUNING),
    build=base.siso_build(PidController), update=base.siso_update, derive=base.tuned_gains, reason=base.siso_reason,
    gains=('kp', 'ti', 'td', 'b', 'c', 'n'), input_limits=base.scalar_limits,
)
