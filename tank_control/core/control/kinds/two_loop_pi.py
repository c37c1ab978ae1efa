"""Controller kind ``two_loop_pi``: the two-loop PI of the mixing tank, with or without
decoupling (003 §2–3), optional gain scheduling (``two_loop.schedule.*``) and measured-disturbance
feedforward (``two_loop.feedforward``). Changes rebuild it, re-initialised from the last (y, u)
(bumpless: the integrals absorb a change of the gains or of the gain table)."""
from __future__ import annotations

from tank_control.core.control.kinds import base
from tank_control.core.control.feedforward import (DISTURBANCES, DisturbanceFeedforward,
                                                   FeedforwardConfig)
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.control.multiloop import TwoLoopPi, TwoLoopPiConfig
from tank_control.core.control.scheduling import GainSchedule, Scheduler
from tank_control.core.plants.mixing_tank import OPERATING_POINT

FLOWS = (OPERATING_POINT.F_H, OPERATING_POINT.F_C)
"""[F_H, F_Cin] [cm³/s] holding the tank at 003's operating point: the warm start and the
default fail-safe output."""


def build(settings: Settings) -> TwoLoopPi:
    controller = TwoLoopPi(settings.config)
    controller.output_names = settings.channels.output_names
    controller.input_names = settings.channels.input_names
    if settings.schedule.active:
        controller.scheduler = Scheduler(settings.schedule)
    if settings.feedforward.active:
        controller.feedforward = DisturbanceFeedforward(settings.feedforward,
                                                        settings.config.sample_time)
        controller.disturbance_names = DISTURBANCES
    return controller


def reason(settings: Settings) -> str | None:
    for name in ('output_names', 'input_names'):
        names = getattr(settings.channels, name)
        if len(names) != 2:
            return f'{name}: {list(names)} must name 2 channels (h and T_out loops)'
    cfg = settings.config
    return base.outputs_within_limits(settings, [(cfg.u_min, cfg.u_max)] * 2)


KIND = ControllerKind(
    name='two_loop_pi',
    description='two-loop PI for the mixing tank with optional decoupling (003 §2-3)',
    config=TwoLoopPiConfig,
    groups=(base.channels(('h', 'T_out'), ('F_H', 'F_Cin')), base.fail_safe(FLOWS),
            base.warm_start(FLOWS), base.group('schedule', GainSchedule),
            base.group('feedforward', FeedforwardConfig)),
    build=build, reason=reason,
    gains=('two_loop.kp_h', 'two_loop.ki_h', 'two_loop.kp_T', 'two_loop.ki_T', 'two_loop.d12',
           'two_loop.d21'),
    disturbances=DISTURBANCES,
    input_limits=lambda s: {name: (s.config.u_min, s.config.u_max)
                            for name in s.channels.input_names},
)
