"""Controller kind ``smith_pi``: Smith predictor with a PI primary (004 §3.6.1)."""
from __future__ import annotations

from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, Settings, Tuning
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.smith import SmithModel, SmithPredictor

PRIMARY = ('kp', 'ti', 'b', 'sample_time', 'u_min', 'u_max', 'du_max', 'anti_windup',
           'tracking_time')
"""The PI primary's parameters (the PID's, td = c = 0)."""
TUNING = ('tuning.rule', 'tuning.te', 'tuning.xi', 'tuning.order')


def derive(values: base.Values) -> dict[str, float]:
    """kp, ti of the PI primary from tuning.rule smith_pi on the internal model (004 eqs.
    3.6.7 with tuning.te, 3.6.9 with tuning.xi)."""
    if values['tuning.rule'] != 'smith_pi':
        return {}
    tuning = Tuning(rule='smith_pi', kind='pi', te=values['tuning.te'], xi=values['tuning.xi'],
                    order=values['tuning.order'])
    gains = tuning.gains(gain=values['smith.gain'], time_constant=values['smith.time_constant'])
    return {'kp': gains['kp'], 'ti': gains['ti']}


def reason(settings: Settings) -> str | None:
    rule, order = settings.tuning.rule, settings.tuning.order
    if rule not in ('none', 'smith_pi'):
        return (f"tuning.rule: {rule!r} does not apply to the Smith predictor; allowed none, "
                'smith_pi')
    if order != 1:
        return (f'tuning.order: {order} designs for a second-order model, but the internal model '
                f'smith.model {settings.config.model!r} is first order; allowed 1')
    if rule == 'smith_pi' and settings.config.gain < 0:
        return ('smith.gain: tuning.rule smith_pi needs a positive model gain (the primary has '
                'kp > 0); allowed (0, 1e9]')
    return base.siso_reason(settings, settings.primary)


def build(settings: Settings) -> SmithPredictor:
    controller = SmithPredictor(settings.config, settings.primary,
                                output_name=settings.channels.output_names[0],
                                input_name=settings.channels.input_names[0])
    if settings.mode.mode == 'manual':
        controller.set_manual(float(settings.mode.manual_output))
    return controller


def update(controller: SmithPredictor, settings: Settings, changed: frozenset[str]) -> bool:
    """PI primary settings and the mode in place (bumpless, the model's history kept); a change
    of the internal model (smith.*) rebuilds, which restarts the model from the steady state
    of u."""
    if any(name.startswith('smith.') for name in changed):
        return False
    primary = controller.primary
    base.set_changed_gains(primary, settings.primary, PRIMARY)
    base.apply_mode(controller, primary.mode, settings, changed)
    return True


KIND = ControllerKind(
    name='smith_pi',
    description='Smith predictor with a PI primary (004 §3.6.1)',
    config=SmithModel,
    groups=(base.group('primary', PidConfig, only=PRIMARY), base.channels(('y',), ('u',)),
            base.MODE, base.fail_safe(), base.warm_start(),
            base.group('tuning', Tuning, only=TUNING)),
    build=build, update=update, derive=derive, reason=reason,
    gains=('kp', 'ti', 'b'),
    input_limits=lambda s: {s.channels.input_names[0]: (s.primary.u_min, s.primary.u_max)},
)
