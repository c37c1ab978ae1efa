"""Controller kind ``two_loop_pi``: the two-loop PI of the mixing tank, with or without
decoupling ([Michalski2021] §2–3), optional gain scheduling (``two_loop.schedule.*``) and measured-disturbance
feedforward (``two_loop.feedforward``), and its multivariable auto-tuning ([Precup2013] §3.7,
``autotune.mode``: core/control/mimo_autotune.py; commands ``~/start_autotune``,
``~/abort_autotune``, ``~/apply_autotune``, ``~/revert_gains``). Changes rebuild it,
re-initialised from the last (y, u) (bumpless: the integrals absorb a change of the gains or of
the gain table)."""
from __future__ import annotations

from typing import Any

from tank_control.core.control.kinds import base
from tank_control.core.control.feedforward import (DISTURBANCES, DisturbanceFeedforward,
                                                   FeedforwardConfig)
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.control.mimo_autotune import (RELAY_SETTINGS, TESTING,
                                                     MimoAutotuneConfig, MimoAutotuneResults,
                                                     MimoAutotuner)
from tank_control.core.control.multiloop import TwoLoopPi, TwoLoopPiConfig
from tank_control.core.control.relay_autotune import (AutotuneCommand, AutotuneConfig,
                                                      AutotuneResults)
from tank_control.core.control.scheduling import GainSchedule, Scheduler
from tank_control.core.plants.mixing_tank import OPERATING_POINT

FLOWS = (OPERATING_POINT.F_H, OPERATING_POINT.F_C)
"""[F_H, F_Cin] [cm³/s] holding the tank at [Michalski2021]'s operating point: the warm start and the
default fail-safe output."""


COMMANDS = ('start_autotune', 'abort_autotune', 'apply_autotune', 'revert_gains')
RESULTS = tuple('autotune.' + n for n in ('state', 'reason', 'state_time', 'cycles'))


def _two_loop(settings: Settings) -> TwoLoopPi:
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


def build(settings: Settings) -> TwoLoopPi | MimoAutotuner:
    """The two-loop PI; with ``autotune.mode`` other than none, inside its auto-tuner."""
    controller = _two_loop(settings)
    if settings.mimo.mode == 'none':
        return controller
    tuner = MimoAutotuner(settings.config, settings.mimo, settings.autotune, pi=controller)
    if settings.command.start:
        tuner.start()
    elif settings.values.get('autotune.state') in TESTING:
        # a live change rebuilds the controller; the parameters still show the test it ends
        tuner.interrupted('parameters changed during the test')
    return tuner


def _command(name: str) -> Any:
    def run(controller: Any) -> tuple[bool, str]:
        if not isinstance(controller, MimoAutotuner):
            return False, 'autotune: autotune.mode is none; set relay, model_zn or model_ls'
        return controller.command(name)
    return run


def results(controller: Any) -> dict[str, Any]:
    return controller.results() if isinstance(controller, MimoAutotuner) else {}


def summary(values: base.Values) -> str:
    """One line of the last design, or '' before one: ``relay: Ku h 0.3897 (Tu 638 s), T 4.492
    (Tu 289.8 s); gains kp_h 0.1158, ki_h 0.0001602, kp_T -1.335, ki_T -0.004066``."""
    if not values.get('autotune.proposed_kp_h') and not values.get('autotune.proposed_ki_h'):
        return ''
    text = f"{values.get('autotune.mode', '?')}: "
    if values.get('autotune.ku_h'):
        text += (f"Ku h {values['autotune.ku_h']:.4g} (Tu {values['autotune.tu_h']:.4g} s), "
                 f"T {values['autotune.ku_T']:.4g} (Tu {values['autotune.tu_T']:.4g} s); ")
    elif values.get('autotune.ls_residual'):
        text += f"least-squares residual {values['autotune.ls_residual']:.3g}; "
    return text + 'gains ' + ', '.join(
        f"{name} {values['autotune.proposed_' + name]:.4g}"
        for name in ('kp_h', 'ki_h', 'kp_T', 'ki_T'))


def reason(settings: Settings) -> str | None:
    for name in ('output_names', 'input_names'):
        names = getattr(settings.channels, name)
        if len(names) != 2:
            return f'{name}: {list(names)} must name 2 channels (h and T_out loops)'
    cfg = settings.config
    return base.outputs_within_limits(settings, [(cfg.u_min, cfg.u_max)] * 2)


KIND = ControllerKind(
    name='two_loop_pi',
    description='two-loop PI for the mixing tank with optional decoupling ([Michalski2021] §2-3)',
    config=TwoLoopPiConfig,
    groups=(base.channels(('h', 'T_out'), ('F_H', 'F_Cin')), base.fail_safe(FLOWS),
            base.warm_start(FLOWS), base.group('schedule', GainSchedule),
            base.group('feedforward', FeedforwardConfig), base.group('mimo', MimoAutotuneConfig),
            base.group('autotune', AutotuneConfig,
                       only=tuple('autotune.' + n for n in RELAY_SETTINGS)),
            base.group('command', AutotuneCommand),
            base.group('results', AutotuneResults, only=RESULTS),
            base.group('mimo_results', MimoAutotuneResults)),
    build=build, reason=reason, results=results, state='autotune.state', summary=summary,
    commands={name: _command(name) for name in COMMANDS},
    gains=('two_loop.kp_h', 'two_loop.ki_h', 'two_loop.kp_T', 'two_loop.ki_T', 'two_loop.d12',
           'two_loop.d21'),
    disturbances=DISTURBANCES,
    input_limits=lambda s: {name: (s.config.u_min, s.config.u_max)
                            for name in s.channels.input_names},
)
