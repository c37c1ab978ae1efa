"""Controller kind ``mpcs``: offset-free MPCS of the mixing tank, analytic or QP ([Michalski2021] §4, §6).
Live changes go through :meth:`Mpcs.configure` (bumpless; ``sample_time`` is read-only)."""
from __future__ import annotations

from tank_control.core.control.kinds import base
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.control.mpcs import Mpcs, MpcsConfig
from tank_control.core.control.mpcs_model import tank_model
from tank_control.core.params import names_of, values_of


def build(settings: Settings) -> Mpcs:
    controller = Mpcs(settings.config)
    controller.output_names = settings.channels.output_names
    controller.input_names = settings.channels.input_names
    return controller


def update(controller: Mpcs, settings: Settings, changed: frozenset[str]) -> bool:
    own = set(names_of(MpcsConfig))
    values = values_of(settings.config)
    controller.configure(**{name: values[name] for name in changed if name in own})
    return True


def adopt(controller: Mpcs, candidate: Mpcs, changed: frozenset[str]) -> bool:
    return controller.adopt(candidate)


def loop_dead_times(settings: Settings) -> dict[str, tuple[float, str]]:
    """Loop ``output_names[i]``–``input_names[i]``: its input's plus its output's delay in the
    prediction model (the tank's τ_C on F_Cin, τ on T_out)."""
    cfg = settings.config
    model = tank_model(cfg.operating_point(), cfg.sample_time)
    ts, ch = cfg.sample_time, settings.channels
    return {y: ((model.input_delays[i] + model.output_delays[i]) * ts,
                f"controller's prediction model (delay of {u} {model.input_delays[i] * ts:g} s "
                f'+ of {y} {model.output_delays[i] * ts:g} s)')
            for i, (y, u) in enumerate(zip(ch.output_names, ch.input_names))}


def input_limits(settings: Settings) -> dict[str, tuple[float, float]]:
    cfg, names = settings.config, settings.channels.input_names
    lo = list(cfg.u_min) * (2 if len(cfg.u_min) == 1 else 1)
    hi = list(cfg.u_max) * (2 if len(cfg.u_max) == 1 else 1)
    return {name: (lo[i], hi[i]) for i, name in enumerate(names)}


KIND = ControllerKind(
    name='mpcs',
    description='offset-free MPCS for the mixing tank, analytic or QP ([Michalski2021] §4, §6)',
    config=MpcsConfig,
    no_linear=('no loop margins: a receding-horizon law whose limits and rate limits make it '
               'nonlinear; unconstrained it is a 2×2 state feedback with an observer, not two '
               'SISO loops, and its margins are not computed (docs/mpcs.md)'),
    groups=(base.channels(Mpcs.output_names, Mpcs.input_names),
            base.warm_start((MpcsConfig().op_F_H, MpcsConfig().op_F_Cin))),
    build=build, update=update, adopt=adopt,
    # every change rebuilds the prediction, QP and (model/estimator changes) Kalman matrices:
    # tens of ms at the default horizons, seconds at the largest
    slow=tuple(n for n in names_of(MpcsConfig) if n != 'sample_time'),
    gains=('mpcs.horizon', 'mpcs.control_horizon', 'mpcs.lambda', 'mpcs.output_weights',
           'mpcs.terminal_weight'),
    input_limits=input_limits, disturbances=Mpcs.disturbance_names,
    loop_dead_times=loop_dead_times,
)
