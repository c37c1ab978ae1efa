"""Controller kind ``smith_pi``: Smith predictor with a PI primary ([Precup2013] §3.6.1), its auto-tuning
chain ([Precup2013] §3.6: relay → ZN PI → kP from a setpoint change → eq. 3.6.2 → eq. 3.6.7/3.6.9;
``autotune.*``, ``~/start_autotune``, ``~/abort_autotune``) and the robustness of the running
loop on its internal model (``robustness.*``, the ``ms_max`` guard)."""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.analysis.linear import LinearController, model_sum
from tank_control.core.analysis.robustness import LoopReport, smith_report, smith_responses
from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, LoopWatch, Settings, Tuning
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import (AutotuneCommand, AutotuneConfig,
                                                      AutotuneResults)
from tank_control.core.control.smith import SmithModel
from tank_control.core.control.smith_autotune import (TESTING, SmithAutotuner, SmithDesign,
                                                      model_of)
from tank_control.core.tuning.model import ProcessModel

PRIMARY = ('kp', 'ti', 'b', 'sample_time', 'u_min', 'u_max', 'du_max', 'anti_windup',
           'tracking_time')
"""The PI primary's parameters (the PID's, td = c = 0)."""
TUNING = ('tuning.rule', 'tuning.te', 'tuning.xi', 'tuning.order')
AUTOTUNE = tuple('autotune.' + name for name in (
    'relay_amplitude', 'hysteresis', 'noise_band', 'bias_correction', 'asymmetry_tol',
    'min_cycles', 'stationarity_tol', 'timeout', 'settle_time', 'settle_band', 'settle_timeout',
    'max_amplitude', 'method', 'start_time'))
"""The relay test's settings the chain uses (its rule is [Precup2013] Table 3.1's ZN PI)."""
RESULTS = tuple('autotune.' + name for name in (
    'state', 'reason', 'state_time', 'cycles', 'ku', 'tu', 'ku_df', 'tu_df', 'model_kind',
    'model_method', 'model_gain', 'model_time_constant', 'model_dead_time',
    'model_time_constant2'))
COMMANDS = ('start_autotune', 'abort_autotune')
GUARDED = ('kp', 'ti', 'b', 'sample_time', 'robustness.ms_max')
"""Parameters whose change the robustness guard checks (smith.* is the model: not refused)."""


def process_model(model: SmithModel) -> ProcessModel:
    """The internal model as a process model (the gain's magnitude; its sign is the loop's,
    :func:`analyse`)."""
    return model_of(model)


def analyse(model: ProcessModel, loop: tuple[PidConfig, float]) -> LoopReport:
    """:func:`smith_report` of the primary on the model; ``loop`` = (primary, sign of the
    model gain): the loop gain is ``kp·sign(K)·|K|``."""
    primary, sign = loop
    return smith_report(model, replace(primary, kp=primary.kp * sign))


def _loop(model: SmithModel, primary: PidConfig) -> tuple[PidConfig, float]:
    return primary, math.copysign(1.0, model.gain)


def _key(loop: tuple[PidConfig, float]) -> tuple[float, ...]:
    primary, sign = loop
    return (primary.kp * sign, primary.ti, primary.b, primary.sample_time)


def _gains(loop: tuple[PidConfig, float]) -> str:
    return f'kp {loop[0].kp:.4g}, ti {loop[0].ti:.4g} s'


def linear(settings: Settings) -> LinearController:
    """The Smith predictor as implemented: the equivalent controller ``C_eq`` (−U/Y) and its
    setpoint path (:func:`smith_responses`) on the internal model, stability on any plant
    ``G`` from ``C·(Gm0 − Gm + G)`` (the closed loop's characteristic equation
    ``1 + C·(Gm0 − Gm + G) = 0``: no hidden poles of ``C_eq``), and the internal model."""
    model = process_model(settings.config)
    primary, sign = _loop(settings.config, settings.primary)
    primary = replace(primary, kp=primary.kp * sign)
    ceq, req, _ = smith_responses(model, primary)
    h = primary.sample_time
    c = fr.pid_feedback_discrete(abs(primary.kp), primary.ti, 0.0, primary.n, sample_time=h)
    c = c * (-1.0 if primary.kp < 0 else 1.0)
    gm, gm0 = model.response(h), replace(model, dead_time=0.0).response(h)

    def characteristic(g: fr.FrequencyResponse) -> fr.FrequencyResponse:
        return c * model_sum(((1.0, gm0), (-1.0, gm), (1.0, g)), g.integrators,
                             g.unstable_poles + gm.unstable_poles)
    return LinearController(
        ceq, f'Smith predictor, PI primary kp {primary.kp:.4g}, ti {primary.ti:.4g} s, '
        f'b {primary.b:g}', req, characteristic, models=(('internal', model),))


def derive(values: base.Values) -> dict[str, float]:
    """kp, ti of the PI primary from tuning.rule smith_pi on the internal model ([Precup2013] eqs.
    3.6.7 with tuning.te, 3.6.9 with tuning.xi)."""
    if values['tuning.rule'] != 'smith_pi':
        return {}
    tuning = Tuning(rule='smith_pi', kind='pi', te=values['tuning.te'], xi=values['tuning.xi'],
                    order=values['tuning.order'])
    gains = tuning.gains(gain=values['smith.gain'], time_constant=values['smith.time_constant'])
    assert gains is not None                      # None only for rule 'none'
    return {'kp': gains['kp'], 'ti': gains['ti']}


def reason(settings: Settings) -> str | None:
    rule, order = settings.tuning.rule, settings.tuning.order
    if rule not in ('none', 'smith_pi'):
        return (f"tuning.rule: {rule!r} does not apply to the Smith predictor; allowed none, "
                'smith_pi')
    model = settings.config
    if rule == 'smith_pi' and order == 1 and model.model != 'fopdt':
        return (f'tuning.order: 1 designs for K/(T s+1) ([Precup2013] eq. 3.6.7), but the internal model '
                f'smith.model is {model.model!r}; allowed 2 with sopdt (T2 = T), or smith.model '
                'fopdt')
    if rule == 'smith_pi' and order == 2 and (model.model != 'sopdt'
                                              or model.time_constant2 != model.time_constant):
        return (f'tuning.order: 2 designs for K/(T s+1)^2 ([Precup2013] eq. 3.6.9), but the internal model '
                f'is smith.model {model.model!r} with smith.time_constant {model.time_constant:g} '
                f's, smith.time_constant2 {model.time_constant2:g} s; allowed sopdt with '
                'smith.time_constant2 = smith.time_constant, or tuning.order 1')
    if rule == 'smith_pi' and settings.config.gain < 0:
        return ('smith.gain: tuning.rule smith_pi needs a positive model gain (the primary has '
                'kp > 0); allowed (0, 1e9]')
    return base.siso_reason(settings, settings.primary) or _inner_reason(settings) or \
        base.guard_reason(
        settings, process_model(settings.config), _loop(settings.config, settings.primary),
        analyse, GUARDED, _gains)


def _inner_reason(settings: Settings) -> str | None:
    """The Smith predictor is its model: on a plant equal to it the loop is the primary on
    the delay-free model, delayed (C·Gm0 of :func:`smith_report`). Unstable there, the
    configuration contradicts itself (e.g. a negative smith.gain, as kp >= 0) and is refused
    without robustness.ms_max, which bounds Ms of the loops that are stable."""
    model, primary = settings.config, settings.primary
    loop = _loop(model, primary)
    try:                                  # the Nyquist count of C·Gm0 alone (no margins)
        with np.errstate(all='ignore'):   # extreme settings: inf/nan points are not stable
            _, _, free = smith_responses(process_model(model),
                                         replace(primary, kp=primary.kp * loop[1]))
            stable = fr.closed_loop_poles_unstable(free) == 0
    except (ArithmeticError, ValueError):
        return None                       # settings the analysis cannot take: checked elsewhere
    if stable:
        return None
    return (f'smith.gain, kp: on the plant it is designed for (its model, smith.gain '
            f'{model.gain:g}) the Smith loop would be unstable ({_gains(loop)}); allowed: '
            'kp·smith.gain > 0 and a PI that is stable on the model')


def _design(settings: Settings) -> SmithDesign:
    t = settings.tuning
    return SmithDesign(order=t.order, te=t.te, xi=t.xi)


def build(settings: Settings) -> SmithAutotuner:
    controller = SmithAutotuner(settings.config, settings.primary, settings.autotune,
                                _design(settings),
                                output_name=settings.channels.output_names[0],
                                input_name=settings.channels.input_names[0])
    controller.ms_max = settings.robustness.ms_max
    if settings.mode.mode == 'manual':
        controller.set_manual(float(settings.mode.manual_output))
    base.attached(controller).loop_watch = LoopWatch(process_model(settings.config),
                                                     settings.robustness.ms_max, analyse, _key)
    if settings.command.start:
        controller.start()
    return controller


def update(controller: SmithAutotuner, settings: Settings, changed: frozenset[str]) -> bool:
    """PI primary settings and the mode in place (bumpless, the model's history kept); a change
    of the internal model (smith.*) rebuilds, which restarts the model from the steady state
    of u. A user's change while the auto-tuning chain runs aborts it first (the Smith
    predictor from before the test resumes); ``autotune.start`` = true starts it."""
    user = changed - {'autotune.start'}
    if user and controller.state in TESTING:
        controller.abort('parameters changed during the test')
    if any(name.startswith('smith.') for name in changed):
        return False
    primary = controller.primary
    base.set_changed_gains(primary, settings.primary, PRIMARY)
    base.apply_mode(controller, primary.mode, settings, changed)
    base.attached(controller).loop_watch.ms_max = settings.robustness.ms_max
    controller.ms_max = settings.robustness.ms_max
    controller.design = _design(settings)
    if settings.autotune != controller.config:
        controller.configure(settings.autotune)
    if 'autotune.start' in changed and settings.command.start:
        controller.start()
    return True


def results(controller: SmithAutotuner) -> dict[str, Any]:
    """The chain's ``autotune.*`` results with the running ``smith.*`` model and primary
    ``kp``, ``ti``, and ``robustness.*`` of the running loop on the internal model."""
    watch = base.attached(controller).loop_watch
    watch.model = process_model(controller.model)
    return {**controller.results(),
            **watch.values(_loop(controller.model, controller.primary.config))}


KIND = ControllerKind(
    name='smith_pi',
    description='Smith predictor with a PI primary ([Precup2013] §3.6.1)',
    config=SmithModel,
    groups=(base.group('primary', PidConfig, only=PRIMARY), base.channels(('y',), ('u',)),
            base.MODE, base.fail_safe(), base.warm_start(),
            base.group('tuning', Tuning, only=TUNING), base.ROBUSTNESS, base.ROBUSTNESS_RESULTS,
            base.group('autotune', AutotuneConfig, only=AUTOTUNE),
            base.group('command', AutotuneCommand),
            base.group('results', AutotuneResults, only=RESULTS)),
    build=build, update=update, derive=derive, reason=reason, results=results,
    state='autotune.state',
    commands=base.forwarded_commands(COMMANDS),
    gains=('kp', 'ti', 'b'),
    input_limits=lambda s: {s.channels.input_names[0]: (s.primary.u_min, s.primary.u_max)},
    linear=linear,
)
