"""Controller kinds by name: parameters, checks, construction and live updates.

``controller_node`` (ROS) and the in-process loop (``core/scenario.py``) both
build their controller with :func:`make_controller` from the same flat
parameter values (dotted names, as in the params file), so a ROS run and an
in-process run execute identical objects.

A kind (:class:`ControllerKind`) supplies

* ``params()`` — its ``ParamSpec`` tuple (gains, limits, mode, tuning, ...);
* ``check(values)`` — relations between parameters (one-line reason or None);
* ``build(values)`` — the :class:`~tank_control.core.interfaces.Controller`;
* ``update(controller, values, changed)`` — apply accepted changes to a
  running controller in place, bumplessly (returning None or True); returning
  False (or ``update=None``) asks for a rebuild: ``step_with_changes`` builds a
  new object and initialises it with ``reset(y, u)`` at that sample's output,
  which is bumpless by the Controller contract;
* ``derive(values, changed)`` — parameter values that follow from others
  (the gains of ``tuning.rule``), written back so ``ros2 param get`` shows them;
* optionally ``results(controller)`` — values the controller produced at run
  time (written back to parameters by the node) and ``commands`` — operator
  commands the node offers as ``std_srvs/Trigger`` services ``~/<name>``
  (e.g. ``start_autotune``, ``abort_autotune`` of issue 6).

Adding a kind (e.g. ``relay_autotune``, ``mpcs``) is local: write a function
returning a ``ControllerKind`` (usually in the controller's own module) and add
one line to ``_KIND_FACTORIES``. The common parameters (``controller`` and the
channel names) are added here; a kind's own specs win on a name clash.

Warm start (every kind): parameter ``initial_output`` — one value per input
channel, read-only — is the output the controller takes over with. At its first
sample with a finite measurement, ``core/loop.py`` and controller_node call
``controller.reset(y, initial_output)`` (``core.loop.warm_start``), so that
sample returns ``initial_output`` when ``y = r`` (bumpless take-over of a plant
running at its operating point). Defaults: the 003 operating-point flows
``[F_H, F_Cin] = [14, 37]`` cm³/s for ``two_loop_pi`` and ``mpcs`` (the inflows
that hold the tank at h = 81 cm, T_out = 2115/63 °C with F_D = 12 cm³/s); ``[0]``
for the SISO kinds, which is the holding input of the shipped SISO plants at rest
(IPDT/FOPDT with ``initial_output`` 0 and no load; an FOPDT started at y0 needs
y0/gain, an IPDT with a load v needs −v — set it). A SISO kind started in
``mode: manual`` takes over with ``manual_output`` instead.

Parameter conventions of this package (ROS parameters cannot hold ``inf``):
``ti = 0`` no integral action, ``du_max = 0`` no rate limit, ``tracking_time
= 0`` the default tracking time; tuning process values of 0 mean "not given".
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from importlib import import_module
from typing import Any

import numpy as np

from tank_control.core.interfaces import Controller
from tank_control.core.params import ParamSpec, check_all

Values = Mapping[str, Any]


def _no_derive(values: Values, changed: frozenset[str]) -> dict[str, Any]:
    return {}


@dataclass(frozen=True)
class ControllerKind:
    """Everything controller_node and the in-process loop need to run one controller type."""

    name: str
    params: Callable[[], tuple[ParamSpec, ...]]
    check: Callable[[Values], str | None]
    build: Callable[[Values], Controller]
    update: Callable[[Controller, Values, frozenset[str]], bool | None] | None
    derive: Callable[[Values, frozenset[str]], dict[str, Any]] = _no_derive
    description: str = ''
    results: Callable[[Controller], Mapping[str, Any]] | None = None
    """Parameter values the running controller produced (an identified ``ku``, the gains
    it switched to, a state name); controller_node writes changed ones back to its
    parameters after each sample (read-only ones included), so ``ros2 param get`` shows them."""
    commands: Mapping[str, Callable[[Controller], tuple[bool, str]]] = field(default_factory=dict)
    """Operator commands by name; controller_node offers each as a ``std_srvs/Trigger``
    service ``~/<name>`` that calls ``commands[name](controller) -> (success, message)``,
    e.g. ``{'start_autotune': lambda c: c.start(), 'abort_autotune': lambda c: c.abort()}``."""
    initial_output: tuple[float, ...] | None = None
    """Default of the ``initial_output`` parameter when the kind's own specs do not define
    it (None: 0 for every default input channel)."""
    state: str | None = None
    """Name of the ``results`` entry that is the controller's state-machine state (e.g.
    ``autotune.state``); controller_node publishes each change on ``~/<name, '.' → '_'>``
    (``std_msgs/String``, reliable, transient local: a late subscriber gets the current
    state) and in ``/diagnostics`` at once."""


# ------------------------------------------------------------------ pid
_GAINS = ('kp', 'ti', 'td', 'b', 'c')


def _pid_tuned(values: Values) -> dict[str, float] | None:
    """Gains of ``tuning.rule`` in parameter convention (SPEC §2.2–2.6), None without a rule."""
    from tank_control.core.control.pid import tuned_gains
    gains = tuned_gains(values)
    if gains is None:
        return None
    out = {
        'kp': float(gains['kp']),
        'ti': float(gains['ti']) if gains.get('ti') is not None else 0.0,
        'td': float(gains['td']) if gains.get('td') is not None else 0.0,
        'b': float(gains['b']) if gains.get('b') is not None else 1.0,
        'c': float(gains['c']) if gains.get('c') is not None else 1.0,
    }
    if out['kp'] < 0:   # reverse-acting process: magnitude here, sign by direct_action
        out['kp'] = -out['kp']
    return out


def _pid_derive(values: Values, changed: frozenset[str]) -> dict[str, Any]:
    """With ``tuning.rule`` set, kp/ti/td/b/c are the rule's (written back as parameters)."""
    tuned = _pid_tuned(values)
    return {} if tuned is None else tuned


def _pid_check(values: Values) -> str | None:
    from tank_control.core.control.pid import check_pid_relations
    reason = check_pid_relations(values)
    if reason:
        return reason
    try:
        tuned = _pid_tuned(values)
    except ValueError as exc:
        return str(exc)
    if tuned is not None:
        for name in _GAINS:
            if not math.isclose(float(values[name]), tuned[name], rel_tol=1e-12, abs_tol=1e-15):
                rule = values['tuning.rule']
                return (f"{name}: {values[name]:g} conflicts with tuning.rule {rule!r}, "
                        f"which gives {tuned[name]:g}; set tuning.rule to none to tune by hand")
    return None


def _pid_build(values: Values) -> Controller:
    from tank_control.core.control.pid import PidController, pid_config_from_params
    config = pid_config_from_params(values)
    controller = PidController(config, output_name=_single(values, 'output_names'),
                               input_name=_single(values, 'input_names'))
    if values.get('mode') == 'manual':
        controller.pid.set_manual(float(values['manual_output']))
    return controller


def _pid_update(controller: Controller, values: Values, changed: frozenset[str]) -> bool:
    """Bumpless: gains and limits through ``Pid2Dof.set_gains`` (the integral
    absorbs the change), then the mode (manual output / bumpless return to auto)."""
    from tank_control.core.control.pid import pid_config_from_params
    pid = controller.pid                      # type: ignore[attr-defined]
    config = asdict(pid_config_from_params(values))
    changes = {k: v for k, v in config.items() if getattr(pid.config, k) != v}
    if changes:
        pid.set_gains(**changes)
    _apply_mode(pid, pid.mode, values, changed)
    return True


def _apply_mode(target: Any, mode_now: str, values: Values, changed: frozenset[str]) -> None:
    """Manual output on request (or when the mode changes), bumpless return to auto."""
    if values['mode'] == 'manual' and ({'mode', 'manual_output'} & changed or mode_now != 'manual'):
        target.set_manual(float(values['manual_output']))
    elif values['mode'] == 'auto' and mode_now != 'auto':
        target.set_auto()


def _pid_kind() -> ControllerKind:
    from tank_control.core.control.pid import pid_params
    return ControllerKind(
        name='pid', params=lambda: pid_params() + _channel_specs(('y',), ('u',)),
        check=_pid_check, build=_pid_build, update=_pid_update, derive=_pid_derive,
        description='SISO 2-DOF PID (000 eq. 19) with filter, limits, anti-windup, tuning rules')


# ---------------------------------------------------------- two_loop_pi
#: 003 operating point of the mixing tank: F_H, F_Cin [cm³/s] that hold h = 81 cm and
#: T_out = 2115/63 °C with F_D = 12 cm³/s at T_D = 33 °C (T_H = 62, T_C = 23 °C).
OPERATING_POINT_FLOWS = (14.0, 37.0)

def _two_loop_check(values: Values) -> str | None:
    from tank_control.core.control.multiloop import check_two_loop_relations
    reason = check_two_loop_relations(values)
    if reason:
        return reason
    for name in ('output_names', 'input_names'):
        if len(values[name]) != 2:
            return f'{name}: {list(values[name])} must name 2 channels (h and T_out loops)'
    safe = list(values['fail_safe_output'])
    lo, hi = values['u_min'], values['u_max']
    if len(safe) != 2 or not all(lo <= v <= hi for v in safe):
        return (f'fail_safe_output: {safe} must be 2 flows (F_H, F_Cin) within the limits '
                f'[{lo:g}, {hi:g}]')
    return None


def _two_loop_build(values: Values) -> Controller:
    from tank_control.core.control.multiloop import TwoLoopPi, two_loop_config_from_params
    controller = TwoLoopPi(two_loop_config_from_params(values))
    controller.output_names = tuple(values['output_names'])
    controller.input_names = tuple(values['input_names'])
    return controller


def _two_loop_kind() -> ControllerKind:
    """Two-loop PI of 003 §2–3; changes rebuild it, re-initialised from the last (y, u)."""
    from tank_control.core.control.multiloop import two_loop_pi_params
    fail_safe = (
        ParamSpec('fail_safe', 'hold', 'on stale or non-finite measurement: hold the last flows '
                  'or send fail_safe_output', choices=('hold', 'output')),
        ParamSpec('fail_safe_output', [14.0, 37.0], 'flows [F_H, F_Cin] sent on a measurement '
                  "fault when fail_safe = 'output' [cm³/s] (default: 003 operating point)",
                  min=0.0, max=1e4),
    )
    return ControllerKind(
        name='two_loop_pi',
        params=lambda: two_loop_pi_params() + fail_safe
        + _channel_specs(('h', 'T_out'), ('F_H', 'F_Cin')),
        check=_two_loop_check, build=_two_loop_build, update=None,
        initial_output=OPERATING_POINT_FLOWS,
        description='two-loop PI for the mixing tank with optional decoupling (003 §2-3)')


# ------------------------------------------------------------- smith_pi
_SMITH_PRIMARY = ('kp', 'ti', 'b', 'u_min', 'u_max', 'du_max', 'anti_windup', 'tracking_time')


def _smith_tuned(values: Values) -> dict[str, float] | None:
    """kp, ti of the PI primary from tuning.rule smith_pi (004 eqs. 3.6.7/3.6.9), else None."""
    if values.get('tuning.rule', 'none') != 'smith_pi':
        return None
    from tank_control.core.control.smith import smith_config_from_params
    cfg = smith_config_from_params(values)
    return {'kp': float(cfg.kp), 'ti': float(cfg.ti) if math.isfinite(cfg.ti) else 0.0}


def _smith_check(values: Values) -> str | None:
    from tank_control.core.control.smith import check_smith_relations
    reason = check_smith_relations(values)
    if reason:
        return reason
    lo, hi = values['u_min'], values['u_max']
    if values['fail_safe'] == 'output' and not lo <= values['fail_safe_output'] <= hi:
        return (f"fail_safe_output: {values['fail_safe_output']:g} is outside the output limits "
                f'[{lo:g}, {hi:g}]')
    tuned = _smith_tuned(values)
    for name, value in (tuned or {}).items():
        if not math.isclose(float(values[name]), value, rel_tol=1e-12, abs_tol=1e-15):
            return (f"{name}: {values[name]:g} conflicts with tuning.rule 'smith_pi', which gives "
                    f'{value:g}; set tuning.rule to none to tune by hand')
    return None


def _smith_derive(values: Values, changed: frozenset[str]) -> dict[str, Any]:
    return _smith_tuned(values) or {}


def _smith_build(values: Values) -> Controller:
    from tank_control.core.control.smith import SmithPredictor, smith_config_from_params
    controller = SmithPredictor(smith_config_from_params(values),
                                output_name=_single(values, 'output_names'),
                                input_name=_single(values, 'input_names'))
    if values.get('mode') == 'manual':
        controller.set_manual(float(values['manual_output']))
    return controller


def _smith_update(controller: Controller, values: Values, changed: frozenset[str]) -> bool:
    """PI primary settings and the mode in place (bumpless, the model's history kept); a
    change of the internal model (smith.*) rebuilds, which restarts the model from the
    steady state of u."""
    if any(name.startswith('smith.') for name in changed):
        return False
    from tank_control.core.control.smith import smith_config_from_params
    cfg = smith_config_from_params(values)
    primary = controller.primary              # type: ignore[attr-defined]
    new = {name: getattr(cfg, name) for name in _SMITH_PRIMARY}
    current = primary.config
    changes = {k: v for k, v in new.items() if getattr(current, k) != v}
    if changes:
        primary.set_gains(**changes)
    controller.config = cfg                   # type: ignore[attr-defined]
    _apply_mode(controller, primary.mode, values, changed)
    return True


def _smith_kind() -> ControllerKind:
    from tank_control.core.control.pid import pid_params
    from tank_control.core.control.smith import smith_params
    fail_safe = tuple(s for s in pid_params() if s.name in ('fail_safe', 'fail_safe_output'))
    return ControllerKind(
        name='smith_pi', params=lambda: smith_params() + fail_safe + _channel_specs(('y',), ('u',)),
        check=_smith_check, build=_smith_build, update=_smith_update, derive=_smith_derive,
        description='Smith predictor with a PI primary (004 §3.6.1)')


def _single(values: Values, name: str) -> str:
    names = list(values[name])
    if len(names) != 1:
        raise ValueError(f'{name}: a SISO controller needs exactly 1 channel name, got {names}')
    return str(names[0])


# ------------------------------------------------------------ registry
_KIND_FACTORIES: dict[str, tuple[str, str]] = {
    # name: (module, function returning a ControllerKind)
    'pid': (__name__, '_pid_kind'),
    'two_loop_pi': (__name__, '_two_loop_kind'),
    'smith_pi': (__name__, '_smith_kind'),
    'mpcs': ('tank_control.core.control.mpcs', 'controller_kind'),
    'relay_autotune': ('tank_control.core.control.relay_autotune', 'relay_autotune_kind'),
}


def kind_names() -> tuple[str, ...]:
    """Names of the controller kinds available in this build (their modules import)."""
    names = []
    for name in _KIND_FACTORIES:
        try:
            get_kind(name)
        except (ImportError, AttributeError):
            continue
        names.append(name)
    return tuple(names)


def get_kind(name: str) -> ControllerKind:
    """The kind called ``name``; ValueError naming the allowed kinds if unknown."""
    if name not in _KIND_FACTORIES:
        raise ValueError(f"controller: {name!r} is not a controller kind; allowed one of "
                         + ', '.join(_KIND_FACTORIES))
    module, function = _KIND_FACTORIES[name]
    return getattr(import_module(module), function)()


def _channel_specs(outputs: tuple[str, ...], inputs: tuple[str, ...]) -> tuple[ParamSpec, ...]:
    return (
        ParamSpec('output_names', list(outputs), 'measured channels read (and their setpoints), '
                  'by name in the measurement/setpoint messages', read_only=True),
        ParamSpec('input_names', list(inputs), 'manipulated channels written, by name in the '
                  'manipulated message', read_only=True),
    )


#: Parameters of the runtime around any controller (controller_node); the
#: in-process loop accepts and ignores them, so one params file serves both.
RUNTIME_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec('clock_mode', 'auto', 'auto: lockstep answering with use_sim_time, else wall; '
              'wall: wall timer every sample_time; sim: timer on /clock; lockstep: answer each '
              'plant tick stamped t_k once measurement and setpoint of t_k are in',
              choices=('auto', 'wall', 'sim', 'lockstep'), read_only=True),
    ParamSpec('stale_samples', 3, 'wall/sim: samples without a measurement after which it is '
              'stale (hold or fail-safe output)', min=1, max=1000),
    ParamSpec('diagnostics_period', 1.0, 'period of /diagnostics [s, wall clock]',
              min=0.05, max=60.0, read_only=True),
)
_IGNORED = frozenset({'use_sim_time'})   # ROS's own parameter, present in every node section


def initial_output_spec(default: list[float]) -> ParamSpec:
    """``initial_output``: the output the controller takes over with (see the module docstring)."""
    return ParamSpec('initial_output', list(default), 'output at the first sample when the '
                     'measurement equals the setpoint: the controller is reset(y, initial_output) '
                     'there (bumpless take-over), one value per input_names channel, clipped '
                     'to the output limits [input units]',
                     min=-1e12, max=1e12, read_only=True)


def controller_specs(name: str) -> tuple[ParamSpec, ...]:
    """The parameters that describe the controller: ``controller`` (read-only) + the kind's own
    (+ ``initial_output`` with the kind's default unless the kind defines it)."""
    kind = get_kind(name)
    common = ParamSpec('controller', name, 'controller kind (set at start-up)',
                       choices=kind_names(), read_only=True)
    own = kind.params()
    runtime = {spec.name for spec in RUNTIME_SPECS}
    specs = tuple(s for s in own if s.name != 'controller' and s.name not in runtime)
    if not any(s.name == 'initial_output' for s in specs):
        inputs = next((s.default for s in specs if s.name == 'input_names'), ['u'])
        default = kind.initial_output or (0.0,) * len(inputs)
        specs += (initial_output_spec([float(v) for v in default]),)
    return (common,) + specs


def specs_for(name: str) -> tuple[ParamSpec, ...]:
    """Every parameter of a controller_node running kind ``name`` (controller + runtime)."""
    return controller_specs(name) + RUNTIME_SPECS


def controller_values(values: Values) -> dict[str, Any]:
    """The controller's own entries of ``values`` (runtime parameters and use_sim_time dropped)."""
    skip = {spec.name for spec in RUNTIME_SPECS} | _IGNORED
    return {k: v for k, v in values.items() if k not in skip}


def complete_values(values: Values) -> dict[str, Any]:
    """The controller's ``values`` with the defaults of the selected kind filled in
    (``controller`` defaults to pid; runtime parameters dropped)."""
    name = str(values.get('controller', 'pid'))
    merged = {spec.name: spec.default for spec in controller_specs(name)}
    merged.update(controller_values(values))
    return merged


def check(values: Values) -> str | None:
    """Every reason the complete parameter ``values`` are invalid, joined; None if valid."""
    name = str(values.get('controller', 'pid'))
    try:
        specs = specs_for(name)
    except (ValueError, ImportError, AttributeError) as exc:
        return str(exc)
    reasons = check_all(specs, {k: v for k, v in values.items() if k not in _IGNORED})
    if reasons:
        return '; '.join(reasons)
    return get_kind(name).check(controller_values(values)) or check_initial_output(values)


def check_initial_output(values: Values) -> str | None:
    """``initial_output`` has one value per input channel (values outside the output limits
    are clipped to them by the reset, so a limit change never invalidates the default)."""
    if 'initial_output' not in values or 'input_names' not in values:
        return None
    u0, inputs = list(values['initial_output']), list(values['input_names'])
    if len(u0) != len(inputs):
        return (f'initial_output: {u0} must hold {len(inputs)} value(s), one per input '
                f'{inputs}')
    return None


def _set_initial_output(controller: Controller, values: Values) -> Controller:
    """The warm-start value ``core.loop.warm_start`` uses: ``initial_output``, or
    ``manual_output`` for a kind started in ``mode: manual`` (the operator's value wins)."""
    if values.get('mode') == 'manual' and 'manual_output' in values:
        u0 = [float(values['manual_output'])]
    else:
        u0 = [float(v) for v in values['initial_output']]
    controller.initial_output = np.array(u0, dtype=float)   # type: ignore[attr-defined]
    return controller


def derive(values: Values, changed: frozenset[str] = frozenset()) -> dict[str, Any]:
    """Values that follow from others (tuning gains), for the complete ``values``."""
    return get_kind(str(values.get('controller', 'pid'))).derive(values, changed)


def make_controller(values: Values) -> Controller:
    """The controller the parameter ``values`` describe (missing names take defaults).

    Derived values (tuning gains) are applied first, exactly as controller_node
    does at start-up. Raises ValueError with the one-line reason(s).
    """
    merged = complete_values(values)
    merged.update(derive(merged, frozenset(values)))
    reason = check({**values, **merged})
    if reason:
        raise ValueError(reason)
    return _set_initial_output(get_kind(merged['controller']).build(merged), merged)


def step_with_changes(controller: Controller, values: Values, changed: frozenset[str],
                      t: float, y: np.ndarray, r: np.ndarray,
                      d: np.ndarray) -> tuple[Controller, np.ndarray]:
    """The sample at which accepted parameter changes take effect, bumplessly.

    Returns ``(controller to use from now on, output of this sample)``. A kind
    with an in-place ``update`` changes the running object, then steps (the
    update keeps the output continuous, e.g. the PID's integral absorbs a gain
    change). Any other kind computes this sample with the old object, then a
    new object built from ``values`` is ``reset(y, u)`` to that output and
    stepped once on the same sample (which returns ``u`` by the Controller
    contract and initialises it), so the output is exactly continuous and the
    new settings act from the next sample.
    """
    kind = get_kind(str(values.get('controller', 'pid')))
    values = controller_values(values)
    if kind.update is not None and kind.update(controller, values, changed) is not False:
        return controller, np.asarray(controller.step(t, y, r, d), dtype=float)
    u = np.asarray(controller.step(t, y, r, d), dtype=float)
    complete = complete_values(values)
    new = _set_initial_output(kind.build(complete), complete)
    new.reset(y, u)
    new.step(t, y, r, d)
    return new, u
