"""The contract every controller kind and plant kind meets, checked on any kind (pure, no
rclpy): the built-in kinds' tests and users' tests call the same functions
(docs/extending.md, "Testing a kind").

Each check raises :class:`ContractError` whose message starts with the kind and the property
that broke (``pid: bumpless live change: kp 1 -> 1.1 moved the output by 0.37 at t = 4 s``)
and returns a :class:`ContractReport` listing the properties checked and those that do not
apply to the kind (e.g. manual/auto for a kind without ``mode``).
"""
from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tank_control.core.control.kinds import registry as controllers
from tank_control.core.control.kinds.base import ControllerKind, Settings
from tank_control.core.interfaces import Controller, Plant
from tank_control.core.params import ConfigError, ParamSpec, config_from
from tank_control.core.plants.kinds.base import PlantKind


class ContractError(AssertionError):
    """A property of the kind contract does not hold; the message says which, with numbers."""


@dataclass
class ContractReport:
    """``checked``: the properties that hold; ``not_applicable``: property → why not."""

    kind: str
    checked: list[str] = field(default_factory=list)
    not_applicable: dict[str, str] = field(default_factory=dict)


def _fail(kind: str, prop: str, detail: str) -> ContractError:
    return ContractError(f'{kind}: {prop}: {detail}')


def _vec(value: Any, n: int) -> np.ndarray:
    arr = np.asarray(value, dtype=float).reshape(-1)
    return np.full(n, float(arr[0])) if arr.size == 1 else arr


# ====================================================================== parameters
def _numeric(spec: ParamSpec) -> bool:
    return isinstance(spec.default, float) and not isinstance(spec.default, bool)


def _refusals(name: str, specs: Sequence[ParamSpec], values: Mapping[str, Any],
              make: Any, report: ContractReport) -> None:
    """Every numeric parameter: NaN, ±inf and a value beyond its range are refused with a
    ConfigError naming it."""
    for spec in specs:
        if not _numeric(spec):
            continue
        bad: list[float] = [math.nan, math.inf, -math.inf]
        if spec.max is not None and math.isfinite(spec.max):
            bad.append(spec.max + max(1.0, abs(spec.max)))
        if spec.min is not None and math.isfinite(spec.min):
            bad.append(spec.min - max(1.0, abs(spec.min)))
        for value in bad:
            try:
                make({**values, spec.name: value})
            except ConfigError as exc:
                if spec.name not in str(exc):
                    raise _fail(name, 'bad parameter values refused',
                                f'{spec.name} = {value!r} was refused with a reason that does '
                                f'not name it: {exc}') from None
                continue
            except (ValueError, ArithmeticError, TypeError) as exc:
                raise _fail(name, 'bad parameter values refused',
                            f'{spec.name} = {value!r} raised {type(exc).__name__}: {exc} '
                            '(expected ConfigError naming the parameter)') from None
            raise _fail(name, 'bad parameter values refused',
                        f'{spec.name} = {value!r} was accepted (allowed {spec.allowed()})')
    report.checked.append('bad parameter values refused')


# ====================================================================== controllers
@dataclass
class _Loop:
    """One controller with its settings and the signals it sees."""

    kind: ControllerKind
    settings: Settings
    controller: Controller
    n_out: int
    n_in: int
    n_d: int
    h: float
    t: float = 0.0

    def step(self, y: np.ndarray, r: np.ndarray, controller: Controller | None = None
             ) -> np.ndarray:
        c = self.controller if controller is None else controller
        return np.asarray(c.step(self.t, y, r, np.zeros(self.n_d)), dtype=float).reshape(-1)


def _build(kind: ControllerKind, values: Mapping[str, Any]) -> tuple[Settings, Controller]:
    settings = controllers.settings(kind, values)
    return settings, controllers.build(kind, settings)


def _limits(kind: ControllerKind, settings: Settings, n_in: int) -> tuple[np.ndarray, np.ndarray]:
    if kind.input_limits is None:
        return np.full(n_in, -math.inf), np.full(n_in, math.inf)
    limits = list(kind.input_limits(settings).values())
    return (np.array([lo for lo, _ in limits], dtype=float),
            np.array([hi for _, hi in limits], dtype=float))


def _signal(k: int, n: int, amplitude: float, seed: int) -> np.ndarray:
    """A deterministic, varied measurement: sums of sines with channel-dependent phases."""
    i = np.arange(n)
    return amplitude * (np.sin(0.37 * k + 1.3 * i + seed) + 0.5 * np.sin(0.113 * k + 0.7 * i))


def check_controller_kind(kind: ControllerKind | str, values: Mapping[str, Any] | None = None,
                          *, y0: Any = 0.0, r0: Any = 0.5, amplitude: float = 0.1,
                          error: float = 100.0, changes: Mapping[str, Any] | None = None,
                          reset_outputs: Sequence[Any] | None = None,
                          windup_samples: int = 2000, recovery_samples: int = 5,
                          tol: float = 1e-9, scenario: str | None = None,
                          scenario_overrides: Sequence[str] = (), out_dir: Any = None
                          ) -> ContractReport:
    """Check the controller kind contract on ``kind`` (a kind or a registered name) with
    parameter ``values`` (missing ones take defaults; give finite output limits).

    Operating point: measurement ``y0 + amplitude·(varied signal)`` around setpoint ``r0``
    (scalars or one value per channel), saturation with errors of ±``error``. Properties:

    * the object meets the Controller protocol (channels, sample time);
    * determinism: two controllers built from the same values, and a deep copy taken while
      running, give bit-identical outputs;
    * reset: after ``reset(y, u)`` the next output at rest (``r = y``) is ``u`` (each of
      ``reset_outputs``; default: three points inside the output limits) to ``tol``;
    * output limits hold under large errors of either sign (setpoint ``r0``), and anti-windup: after
      ``windup_samples`` saturated, the output leaves the limit within ``recovery_samples``
      once the measurement reverses the error;
    * manual/auto (kinds with ``mode``): manual output applied at the change, held, a
      bumpless return to auto (the first automatic output, at the last manual sample's
      measurement, equals the manual output), and a controller started in manual outputs
      ``manual_output`` first;
    * bumpless live change: each of ``changes`` (name → new value; default: each changeable
      float parameter of the kind's own configuration, +10 %) applied with
      ``registry.step_with_changes`` at a sample whose measurement equals the previous
      one leaves this sample's output within ``tol`` of the unchanged twin's (the new
      setting acts on what changes from then on);
    * bad values refused: NaN, ±inf and out-of-range values of every numeric parameter are
      refused with a ConfigError naming it; a live change that is prepared and then dropped
      (refused) leaves the running controller untouched (its outputs stay the twin's);
    * lockstep == in-process (with ``scenario``: :func:`check_lockstep` on that file).
    """
    if isinstance(kind, str):
        kind = controllers.get_kind(kind)
    values = dict(values or {})
    name = kind.name
    report = ContractReport(name)
    try:
        settings, controller = _build(kind, values)
    except (ValueError, ArithmeticError) as exc:
        raise _fail(name, 'build', f'the values {values} make no controller: {exc}') from None
    for member in ('output_names', 'input_names', 'disturbance_names', 'sample_time', 'reset',
                   'step', 'status'):
        if not hasattr(controller, member):
            raise _fail(name, 'Controller protocol', f'the controller has no {member!r}')
    h = float(controller.sample_time)
    if not (math.isfinite(h) and h > 0):
        raise _fail(name, 'Controller protocol', f'sample_time {h!r} is not a positive number')
    n_out, n_in = len(controller.output_names), len(controller.input_names)
    n_d = len(controller.disturbance_names)
    report.checked.append('Controller protocol')
    y0v, r0v = _vec(y0, n_out), _vec(r0, n_out)
    lo, hi = _limits(kind, settings, n_in)

    def loop(c: Controller | None = None) -> _Loop:
        if c is None:
            c = _build(kind, values)[1]
        return _Loop(kind, settings, c, n_out, n_in, n_d, h)

    def run(lp: _Loop, samples: int, start: int = 0, seed: int = 0,
            c: Controller | None = None) -> np.ndarray:
        out = []
        for k in range(start, start + samples):
            lp.t = k * h
            out.append(lp.step(y0v + _signal(k, n_out, amplitude, seed), r0v, c))
        return np.array(out)

    # ------------------------------------------------------------- determinism
    a, b = loop(), loop()
    ua, ub = run(a, 200), run(b, 200)
    if not np.array_equal(ua, ub, equal_nan=True):
        k = int(np.argmax(np.any(ua != ub, axis=1)))
        raise _fail(name, 'determinism', f'two controllers built from the same values differ '
                    f'at sample {k}: {ua[k].tolist()} vs {ub[k].tolist()}')
    twin = copy.deepcopy(a.controller)
    ua, ut = run(a, 100, 200), run(a, 100, 200, c=twin)
    if not np.array_equal(ua, ut, equal_nan=True):
        k = int(np.argmax(np.any(ua != ut, axis=1)))
        raise _fail(name, 'determinism', f'a deep copy taken at sample 200 differs from the '
                    f'original at sample {200 + k}: {ut[k].tolist()} vs {ua[k].tolist()}')
    if not np.all(np.isfinite(ua)):
        raise _fail(name, 'determinism', f'non-finite output {ua[~np.isfinite(ua)][:3]}')
    report.checked.append('determinism')

    # ------------------------------------------------------------------- reset
    if reset_outputs is None:
        finite_lo = np.where(np.isfinite(lo), lo, -1.0)
        finite_hi = np.where(np.isfinite(hi), hi, 1.0)
        reset_outputs = [finite_lo + f * (finite_hi - finite_lo) for f in (0.25, 0.5, 0.8)]
    for target in reset_outputs:
        target = _vec(target, n_in)
        lp = loop()
        run(lp, 50)
        y = y0v + _signal(50, n_out, amplitude, 0)
        lp.controller.reset(y, target)
        lp.t = 50 * h
        u = lp.step(y, y)                       # at rest: the setpoint is the measurement
        if not np.allclose(u, target, rtol=0, atol=tol * (1 + np.max(np.abs(target)))):
            raise _fail(name, 'reset', f'after reset(y={y.tolist()}, u={target.tolist()}) the '
                        f'next output is {u.tolist()} (differs by '
                        f'{np.max(np.abs(u - target)):.3g}; tolerance {tol:g})')
    report.checked.append('reset')

    # ------------------------------------------------------ limits, anti-windup
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        report.not_applicable['output limits and anti-windup'] = 'no finite output limits'
    else:
        for sign in (1.0, -1.0):
            lp = loop()
            r = r0v.copy()
            y = r0v - sign * error                   # error r − y = sign·error
            us = []
            for k in range(windup_samples):
                lp.t = k * h
                us.append(lp.step(y, r))
            us_arr = np.array(us)
            over = np.max(np.maximum(us_arr - hi, lo - us_arr))
            if over > tol * (1 + np.max(np.abs(hi - lo))):
                k = int(np.argmax(np.max(np.maximum(us_arr - hi, lo - us_arr), axis=1)))
                raise _fail(name, 'output limits', f'output {us_arr[k].tolist()} at sample {k} '
                            f'is outside [{lo.tolist()}, {hi.tolist()}] by {over:.3g} (error '
                            f'{sign * error:g})')
            limit = hi if sign > 0 else lo
            at_limit = np.isclose(us_arr[-1], limit, rtol=0, atol=1e-9 * (1 + abs(limit)))
            if not np.any(at_limit):
                report.not_applicable['anti-windup'] = (
                    f'the output {us_arr[-1].tolist()} did not reach the limit '
                    f'{limit.tolist()} with error {sign * error:g}')
                continue
            y = r0v + sign * error                   # the measurement reverses the error
            left = None
            for j in range(recovery_samples):
                lp.t = (windup_samples + j) * h
                u = lp.step(y, r)
                if np.any(np.abs(u - limit)[at_limit] > 1e-9 * (1 + np.abs(limit[at_limit]))):
                    left = j
                    break
            if left is None:
                raise _fail(name, 'anti-windup', f'after {windup_samples} samples at the limit '
                            f'{limit.tolist()} (error {sign * error:g}) the output is still '
                            f'{u.tolist()} {recovery_samples} samples after the error reversed '
                            f'to {-sign * error:g}')
        report.checked.append('output limits and anti-windup')

    # ------------------------------------------------------------- manual/auto
    if not settings.has('mode'):
        report.not_applicable['manual/auto'] = 'the kind has no mode parameter'
    else:
        manual = 0.5 * (np.where(np.isfinite(lo), lo, -1.0) + np.where(np.isfinite(hi), hi, 1.0))
        manual_value = [float(x) for x in manual] if n_in > 1 else float(manual[0])
        lp = loop()
        run(lp, 30)
        y = y0v + _signal(30, n_out, amplitude, 0)
        lp.t = 30 * h
        changed = {**values, 'mode': 'manual', 'manual_output': manual_value}
        c, u = _change(lp, changed, {'mode', 'manual_output'}, y, r0v)
        if not np.allclose(u, manual, atol=tol * (1 + np.max(np.abs(manual)))):
            raise _fail(name, 'manual/auto', f'manual_output {manual.tolist()} set, the output '
                        f'at that sample is {u.tolist()}')
        lp.controller = c
        held = run(lp, 20, 31)
        if not np.allclose(held, manual, atol=tol * (1 + np.max(np.abs(manual)))):
            raise _fail(name, 'manual/auto', f'in manual the output moved to '
                        f'{held[np.argmax(np.max(np.abs(held - manual), axis=1))].tolist()} '
                        f'(manual_output {manual.tolist()})')
        lp.t = 51 * h                           # the last manual sample's measurement
        c, u = _change(lp, {**changed, 'mode': 'auto'}, {'mode'},
                       y0v + _signal(50, n_out, amplitude, 0), r0v)
        if not np.allclose(u, manual, atol=max(tol, 1e-9) * (1 + np.max(np.abs(manual)))):
            raise _fail(name, 'manual/auto', f'back to auto the output jumped from '
                        f'{manual.tolist()} to {u.tolist()}')
        started = loop(_build(kind, changed)[1])           # started in manual
        started.t = 0.0
        u = started.step(y0v + _signal(0, n_out, amplitude, 0), r0v)
        if not np.allclose(u, manual, atol=tol * (1 + np.max(np.abs(manual)))):
            raise _fail(name, 'manual/auto', f'started with mode manual, manual_output '
                        f'{manual.tolist()}, the first output is {u.tolist()}')
        report.checked.append('manual/auto')

    # ------------------------------------------------------ bumpless live change
    if changes is None:
        changes = _default_changes(kind, settings)
    for param_name, new_value in changes.items():
        lp, twin_lp = loop(), loop()
        run(lp, 60)
        run(twin_lp, 60)
        y = y0v + _signal(59, n_out, amplitude, 0)    # the previous sample's measurement
        lp.t = twin_lp.t = 60 * h
        try:
            c, u = _change(lp, {**values, param_name: new_value}, {param_name}, y, r0v)
        except ConfigError as exc:
            raise _fail(name, 'bumpless live change', f'{param_name} -> {new_value!r} refused: '
                        f'{exc}') from None
        u_twin = twin_lp.step(y, r0v)
        if not np.allclose(u, u_twin, rtol=0, atol=tol * (1 + np.max(np.abs(u_twin)))):
            raise _fail(name, 'bumpless live change', f'{param_name} '
                        f'{settings.values.get(param_name)!r} -> {new_value!r} at t = '
                        f'{60 * h:g} s moved the output from {u_twin.tolist()} to {u.tolist()} '
                        f'(by {np.max(np.abs(u - u_twin)):.3g}; tolerance {tol:g})')
    report.checked.append(f'bumpless live change ({", ".join(changes) or "none changeable"})')

    # -------------------------------------------------------- refused values, changes
    _refusals(name, kind.specs(), values, lambda v: controllers.settings(kind, v), report)
    candidates = dict(changes) or _default_changes(kind, settings)
    if not candidates:
        report.not_applicable['refused change leaves the controller untouched'] = (
            'no changeable float parameter')
    else:
        param_name, new_value = next(iter(candidates.items()))
        lp, twin_lp = loop(), loop()
        run(lp, 40)
        run(twin_lp, 40)
        y = y0v + _signal(40, n_out, amplitude, 0)
        new_settings = controllers.settings(kind, {**values, param_name: new_value},
                                            given={param_name})
        u_last = run(twin_lp, 1, 40)[0]
        run(lp, 1, 40)
        controllers.prepare_change(kind, lp.controller, new_settings, frozenset({param_name}),
                                   trial=(41 * h, y, r0v, np.zeros(n_d)), u_last=u_last)
        after, twin_after = run(lp, 50, 41), run(twin_lp, 50, 41)
        if not np.array_equal(after, twin_after, equal_nan=True):
            k = int(np.argmax(np.any(after != twin_after, axis=1)))
            raise _fail(name, 'refused change leaves the controller untouched',
                        f'a change of {param_name} prepared and dropped changed the output at '
                        f'sample {41 + k}: {after[k].tolist()} vs {twin_after[k].tolist()}')
        report.checked.append('refused change leaves the controller untouched')

    if scenario is not None:
        check_lockstep(scenario, scenario_overrides, out_dir=out_dir)
        report.checked.append('lockstep == in-process')
    else:
        report.not_applicable['lockstep == in-process'] = 'no scenario given'
    return report


def _change(lp: _Loop, values: Mapping[str, Any], changed: set[str], y: np.ndarray,
            r: np.ndarray) -> tuple[Controller, np.ndarray]:
    """A live change as controller_node applies it at this sample."""
    new = controllers.settings(lp.kind, values, given=changed)
    c, u = controllers.step_with_changes(lp.kind, lp.controller, new, frozenset(changed),
                                         lp.t, y, r, np.zeros(lp.n_d))
    return c, np.asarray(u, dtype=float).reshape(-1)


_NOT_BUMPLESS = ('u_min', 'u_max', 'du_max', 'sample_time', 'manual_output', 'fail_safe_output',
                 'initial_output', 'tracking_time')
"""Parameters whose change is not expected to keep the output: limits (the output is clipped
to them), the sample time, outputs used only in other modes or at start-up."""


def _default_changes(kind: ControllerKind, settings: Settings) -> dict[str, Any]:
    """Each changeable float parameter of the kind's own configuration, +10 % (0 → its
    minimum's distance or 0.1), kept within its range; derived ones left out."""
    from tank_control.core.params import specs_of
    derived = set(kind.derive(settings.values)) if kind.derive is not None else set()
    out: dict[str, Any] = {}
    for spec in specs_of(kind.config):
        if spec.read_only or not _numeric(spec) or spec.name in derived:
            continue
        if spec.name in _NOT_BUMPLESS:
            continue
        value = settings.values[spec.name]
        if not isinstance(value, float) or not math.isfinite(value):
            continue
        new = value * 1.1 if value != 0 else 0.1
        if spec.max is not None and new > spec.max:
            new = value - 0.1 * abs(value)
        if spec.min is not None and new < spec.min:
            continue
        try:
            controllers.settings(kind, {**settings.values, spec.name: new}, given={spec.name})
        except ConfigError:
            continue
        out[spec.name] = new
    return out


# ========================================================================== plants
def check_plant_kind(kind: PlantKind | str, values: Mapping[str, Any] | None = None, *,
                     u: Any = 1.0, sample_time: float = 0.1, steps: int = 300,
                     tol: float = 1e-9) -> ContractReport:
    """Check the plant kind contract on ``kind`` with parameter ``values``; inputs vary
    around ``u`` (scalar or one per input), ``steps`` steps of ``sample_time`` [s]:

    * the object meets the Plant protocol; outputs finite, one per output name;
    * determinism: two plants from the same values give bit-identical outputs;
    * reset: back to the initial outputs, then the same run as a new plant;
    * bad parameter values (NaN, ±inf, out of range) refused with a ConfigError naming them;
    * live changes: ``configure`` accepts a changeable parameter and refuses a read-only one
      with a ValueError naming it;
    * linear description (kinds with ``linear``): the model's exact ZOH transfer function
      equals the plant's simulated pulse response (z-transform at points off the unit circle)
      to 1e-6 relative, gain magnitude.
    """
    from tank_control.core.params import specs_of
    if isinstance(kind, str):
        from tank_control.core.plants.kinds import registry as plants
        kind = plants.get_kind(kind)
    values = dict(values or {})
    name = kind.name
    report = ContractReport(name)

    def make() -> Plant:
        return kind.make(values)

    plant = make()
    for member in ('output_names', 'input_names', 'disturbance_names', 'reset', 'outputs',
                   'step', 'status'):
        if not hasattr(plant, member):
            raise _fail(name, 'Plant protocol', f'the plant has no {member!r}')
    n_in, n_d = len(plant.input_names), len(plant.disturbance_names)
    y_start = np.asarray(plant.outputs(), dtype=float)
    if y_start.shape != (len(plant.output_names),) or not np.all(np.isfinite(y_start)):
        raise _fail(name, 'Plant protocol', f'outputs() {y_start.tolist()} must be finite, one '
                    f'per output {list(plant.output_names)}')
    report.checked.append('Plant protocol')
    u0 = _vec(u, n_in)
    d0 = np.zeros(n_d)

    def run(p: Plant) -> np.ndarray:
        ys = []
        for k in range(steps):
            ys.append(np.asarray(p.outputs(), dtype=float).copy())
            p.step(u0 * (1.0 + 0.2 * np.sin(0.21 * k + np.arange(n_in))), d0, sample_time)
        return np.array(ys)

    ya, yb = run(plant), run(make())
    if not np.array_equal(ya, yb):
        k = int(np.argmax(np.any(ya != yb, axis=1)))
        raise _fail(name, 'determinism', f'two plants from the same values differ at step {k}: '
                    f'{ya[k].tolist()} vs {yb[k].tolist()}')
    if not np.all(np.isfinite(ya)):
        raise _fail(name, 'determinism', 'non-finite outputs under bounded inputs')
    report.checked.append('determinism')
    plant.reset()
    y_reset = np.asarray(plant.outputs(), dtype=float)
    if not np.array_equal(y_reset, y_start):
        raise _fail(name, 'reset', f'outputs after reset() {y_reset.tolist()} differ from the '
                    f'initial {y_start.tolist()}')
    again = run(plant)
    if not np.allclose(again, ya, rtol=0, atol=tol * (1 + np.max(np.abs(ya)))):
        raise _fail(name, 'reset', f'a run after reset() differs from a new plant\'s by '
                    f'{np.max(np.abs(again - ya)):.3g}')
    report.checked.append('reset')

    _refusals(name, kind.specs(), values, lambda v: kind.make(v), report)

    specs = specs_of(kind.config)
    changeable = [s for s in specs if not s.read_only and _numeric(s)]
    read_only = [s for s in specs if s.read_only]
    p = make()
    configure = getattr(p, 'configure', None)
    if configure is None:
        report.not_applicable['live changes'] = 'the plant has no configure()'
    else:
        for spec in changeable[:1]:
            config_now: Any = getattr(p, 'config', None)
            value: Any = getattr(config_now, spec.name, spec.default)
            new = value * 1.1 if value else 0.1
            if spec.max is not None and new > spec.max:
                new = value * 0.9
            configure(**{spec.name: new})
            now = getattr(getattr(p, 'config', None), spec.name, new)
            if now != new:
                raise _fail(name, 'live changes', f'configure({spec.name}={new!r}) left it '
                            f'at {now!r}')
        for spec in read_only:
            try:
                configure(**{spec.name: spec.default})
            except ValueError as exc:
                if spec.name not in str(exc):
                    raise _fail(name, 'live changes', f'read-only {spec.name} refused with a '
                                f'reason that does not name it: {exc}') from None
            else:
                raise _fail(name, 'live changes', f'read-only {spec.name} was changed live')
        report.checked.append('live changes')

    if kind.linear is None:
        report.not_applicable['linear description'] = 'the kind has none (PlantKind.linear)'
    else:
        model = kind.linear(config_from(kind.config, values))
        if model is None:
            report.not_applicable['linear description'] = 'none for these values'
        else:
            _check_linear_plant(name, kind, values, model, sample_time)
            report.checked.append('linear description')
    return report


def _check_linear_plant(name: str, kind: PlantKind, values: Mapping[str, Any], model: Any,
                        h: float, samples: int = 3000) -> None:
    """The plant's pulse response (deviation from the unforced run) against the model's ZOH
    transfer function at points ``z = ρ·e^(jθ)`` (ρ > 1 makes the sums converge)."""
    base, pulsed = kind.make(values), kind.make(values)
    n_in, n_d = len(base.input_names), len(base.disturbance_names)
    amplitude = 1e-3
    p = np.empty(samples)
    ub = np.zeros(n_in)
    up = ub.copy()
    up[0] = amplitude
    d = np.zeros(n_d)
    for k in range(samples):
        p[k] = (pulsed.outputs()[0] - base.outputs()[0]) / amplitude
        base.step(ub, d, h)
        pulsed.step(up if k == 0 else ub, d, h)
    peak = float(np.max(np.abs(p))) or 1.0
    tail = abs(p[-1]) / peak
    rho = 1.1 * max(1.0, (tail * 1e3) ** (2.0 / samples))
    g = model.response(h)
    k = np.arange(samples)
    for theta in (0.05, 0.3, 1.0, 2.5):
        z = rho * np.exp(1j * theta)
        sim = complex(np.sum(p * z ** (-k.astype(float))))
        ref = complex(g.at(np.array([z]))[0])
        if min(abs(sim - ref), abs(sim + ref)) > 1e-6 * max(abs(ref), 1e-12):
            raise _fail(name, 'linear description', f'the model {model.describe()} gives '
                        f'G(z) = {ref:.6g} at z = {z:.4g}, the simulated plant {sim:.6g} '
                        f'(sample time {h:g} s)')


# ========================================================================= scenarios
def run_scenario(path: Any, overrides: Sequence[str] = (), *, mode: str = 'in-process',
                 out_dir: Any = None, duration: float | None = None) -> dict[str, Any]:
    """Run a scenario file and return its metrics (metrics.json as a dict). ``mode``:
    ``in-process`` (core/loop.py, no ROS) or a clock mode of a ROS run (``lockstep``,
    ``sim``, ``wall``: the nodes as processes in the environment's ROS_DOMAIN_ID).
    ``out_dir``: where the run's files go (default: a temporary directory, removed)."""
    return _run(path, overrides, mode, out_dir, duration).metrics


def _run(path: Any, overrides: Sequence[str], mode: str, out_dir: Any,
         duration: float | None) -> Any:
    import tempfile
    from pathlib import Path

    from tank_control.harness import runner
    in_process = mode == 'in-process'
    if out_dir is None:
        with tempfile.TemporaryDirectory(prefix='tank_control_run_') as tmp:
            return runner.run(path, Path(tmp) / 'run', mode=None if in_process else mode,
                              duration=duration, overrides=list(overrides),
                              in_process=in_process)
    return runner.run(path, Path(out_dir), mode=None if in_process else mode, duration=duration,
                      overrides=list(overrides), in_process=in_process)


def check_lockstep(path: Any, overrides: Sequence[str] = (), *, tol: float = 1e-9,
                   out_dir: Any = None, duration: float | None = None) -> float:
    """Run ``path`` in lockstep over ROS 2 and in-process; every trace column must agree to
    ``tol``. Returns the largest difference; ContractError naming the column and time."""
    import tempfile
    from pathlib import Path
    with tempfile.TemporaryDirectory(prefix='tank_control_lockstep_') as tmp:
        base = Path(out_dir) if out_dir is not None else Path(tmp)
        ros = _run(path, overrides, 'lockstep', base / 'lockstep', duration).trace
        ref = _run(path, overrides, 'in-process', base / 'in_process', duration).trace
    if len(ros) != len(ref):
        raise _fail(str(path), 'lockstep == in-process', f'{len(ros)} rows in lockstep, '
                    f'{len(ref)} in-process')
    worst = 0.0
    for column, expected in ref.columns.items():
        got = np.asarray(ros.columns.get(column, []), dtype=float)
        expected = np.asarray(expected, dtype=float)
        if got.shape != expected.shape:
            raise _fail(str(path), 'lockstep == in-process', f'column {column} missing or of '
                        f'another length in the lockstep trace')
        diff = np.abs(got - expected)
        diff[np.isnan(got) & np.isnan(expected)] = 0.0
        if diff.size and (np.nanmax(diff) > tol or np.any(np.isnan(diff))):
            k = int(np.nanargmax(diff))
            t = ref.columns['t'][k] if 't' in ref.columns else k
            raise _fail(str(path), 'lockstep == in-process', f'{column} differs by '
                        f'{diff[k]:.3g} at t = {t} ({got[k]!r} vs {expected[k]!r}; tolerance '
                        f'{tol:g})')
        worst = max(worst, float(np.nanmax(diff)) if diff.size else 0.0)
    return worst
