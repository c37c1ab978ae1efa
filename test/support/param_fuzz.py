"""Hostile parameter values for every controller and plant kind, and what a node does with them.

The kinds and their parameters come from the registries and node specs
(``core/node_specs.py``): nothing here names a kind. For a change (one or a few parameters of
one node) :func:`verdict` answers as the nodes would:

* ``file``: the values are start-up values (a params file, ``--set``): the scenario is
  validated as the nodes validate their start-up values (``core/scenario.validate``: each spec,
  the kind's derived values and relations, the ranges, the sample-time relation);
* ``live``: the values are a ``ros2 param set`` on a running node, checked as
  ``nodes/params.ParameterBinding`` and the node's cross-check do (read-only refused, each
  spec, the derived values, the whole candidate through ``controller_setup`` / ``plant_setup``,
  a controller change built and tried from the last sample by ``registry.prepare_change``) and
  applied at the next sample as the node applies it.

A refused change must come with a one-line reason (a ``ConfigError``/``ValueError`` text); an
accepted one is run through the in-process loop (``core/loop.py``, with the nodes' guards) for
at least :data:`SAMPLES` controller samples, and must stay alive, finite and not diverge
(:func:`diverged`). Any other exception anywhere is a crash of the node.
"""
from __future__ import annotations

import math
import signal
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from tank_control.core import node_specs, params_file, scenario
from tank_control.core.control.kinds import registry as controllers
from tank_control.core.interfaces import NS_PER_S, to_ns
from tank_control.core.loop import iter_loop, loop_columns
from tank_control.core.params import ConfigError, ParamSpec, coerce
from tank_control.core.plants.kinds import registry as plants

SAMPLES = 200
"""Controller samples an accepted change must survive."""
SETTLE = 10
"""Samples before the setpoint step (and before a live change)."""
CASE_SECONDS = 300
"""Wall time one case may take before it counts as a frozen loop."""
TICK_SECONDS = 10.0
"""Wall time one tick of the loop may take before it counts as a frozen loop."""
DIVERGENCE = 1e3
"""Growth of the tracking error over the run (last quarter vs second quarter), and distance
above the default run's, that count as divergence (a saturated integrator grows linearly,
well below this; an unstable loop grows geometrically)."""

INT64 = 2 ** 63


# ------------------------------------------------------------------------------ the loops
@dataclass(frozen=True)
class Target:
    """One node to fuzz: ``node`` ('controller' or 'plant'), its ``kind``, the base scenario
    sections (the kind with default parameters, in a loop with a partner kind)."""

    node: str
    kind: str
    sections: Mapping[str, Mapping[str, Any]]
    source: str = 'defaults'

    def specs(self) -> tuple[ParamSpec, ...]:
        values = self.sections[self.node]
        if self.node == 'plant':
            return node_specs.plant_specs(self.kind)
        return node_specs.controller_specs(self.kind, values)


def _fits(controller: Any, plant: Any) -> bool:
    return (set(controller.output_names) <= set(plant.output_names)
            and set(controller.input_names) <= set(plant.input_names)
            and set(controller.disturbance_names) <= set(plant.disturbance_names))


def base_sections(controller_kind: str, plant_kind: str) -> dict[str, dict[str, Any]]:
    """A loop of the two kinds with default parameters: the plant ticks at the controller's
    sample time, the setpoint steps by 1 from the plant's rest output after SETTLE samples."""
    controller = controllers.make_controller(controller_kind, {})
    plant = plants.make_plant(plant_kind)
    ts = controller.sample_time
    y0 = dict(zip(plant.output_names, plant.outputs().tolist()))
    reference: dict[str, Any] = {'setpoint.channels': list(controller.output_names)}
    for name in controller.output_names:
        reference[f'setpoint.{name}.times'] = [0.0, SETTLE * ts]
        reference[f'setpoint.{name}.values'] = [y0[name], y0[name] + 1.0]
    return {'plant': {'plant': plant_kind, 'sample_time': ts},
            'controller': {'controller': controller_kind}, 'reference': reference}


CONFIGS = Path(__file__).resolve().parents[2] / 'config'


@cache
def targets() -> tuple[Target, ...]:
    """Every controller kind (with the first plant kind its default loop runs well on) and
    every plant kind (with the first such controller kind), then the controller and plant of
    each shipped ``config/*.yaml`` (a tuning rule, an auto-tuner, limits as users set them)."""
    out = []
    for path in sorted(CONFIGS.glob('*.yaml')):
        sections = {k: v for k, v in params_file.read(path).items() if k in node_specs.NODES}
        for node in ('controller', 'plant'):
            sections[node] = scenario.node_values(sections, node)
        sections['reference'] = scenario.node_values(sections, 'reference')
        if default_run(freeze(sections)) is None:
            raise AssertionError(f'{path.name}: its loop does not run well in process')
        for node in ('controller', 'plant'):
            out.append(Target(node, node_specs.kind_of(node, sections[node]), sections,
                              path.name))
    for node, kinds, partners in (('controller', controllers.KINDS, plants.KINDS),
                                  ('plant', plants.KINDS, controllers.KINDS)):
        for kind in kinds:
            for partner in partners:
                ck, pk = (kind, partner) if node == 'controller' else (partner, kind)
                if not _fits(controllers.make_controller(ck, {}), plants.make_plant(pk)):
                    continue
                sections = base_sections(ck, pk)
                if default_run(freeze(sections)) is not None:
                    out.append(Target(node, kind, sections))
                    break
            else:
                raise AssertionError(f'no partner kind runs the default loop of {node} {kind}')
    return tuple(out)


def freeze(sections: Mapping[str, Mapping[str, Any]]) -> tuple:
    return tuple((k, tuple((n, _hashable(v)) for n, v in sorted(s.items())))
                 for k, s in sorted(sections.items()))


def _hashable(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


def _thaw(frozen: tuple) -> dict[str, dict[str, Any]]:
    return {k: {n: list(v) if isinstance(v, tuple) else v for n, v in s} for k, s in frozen}


@cache
def default_run(frozen: tuple) -> Run | None:
    """The run of the default loop (None if it does not run well)."""
    sections = _thaw(frozen)
    built = scenario.build(sections)
    run = simulate(built, None)
    if run.broken is not None:
        return None
    return run


@dataclass
class Run:
    """What a loop did: the tracking error per controller sample, the outputs, or why it
    broke."""

    error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    u: np.ndarray = field(default_factory=lambda: np.zeros(0))
    broken: str | None = None


class _Frozen(Exception):
    pass


@contextmanager
def _deadline(seconds: int) -> Iterator[None]:
    def alarm(signum: int, frame: Any) -> None:
        raise _Frozen()
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


class _LiveController:
    """The running controller as controller_node holds it: the accepted change (a
    ``registry.PreparedChange``, made when it was accepted) takes effect at the first sample
    at or after ``at`` [s]."""

    def __init__(self, controller: Any, at: float, accept: Any) -> None:
        self._c = controller
        self._at = at
        self._accept = accept       # (t, y, r, d, u_last) of the last sample -> prepared
        self._prepared = None
        self._last: tuple | None = None
        self._u: np.ndarray | None = None
        self.output_names = controller.output_names
        self.input_names = controller.input_names
        self.disturbance_names = controller.disturbance_names
        self.sample_time = controller.sample_time
        self.initial_output = getattr(controller, 'initial_output', None)
        self.refused: str | None = None

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        self._c.reset(y, u)

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        if self._at is not None and t >= self._at - 1e-9 and self._last is not None:
            self._at = None
            try:
                prepared = self._accept(*self._last, self._u)
            except (ConfigError, ValueError) as exc:
                self.refused = str(exc)
                prepared = None
            if prepared is not None:
                self._c, u = prepared.take_effect(self._c, t, y, r, d)
                self._u = np.asarray(u, dtype=float)
                self._last = (t, y, r, d)
                return self._u
        u = np.asarray(self._c.step(t, y, r, d), dtype=float)
        self._last, self._u = (t, y, r, d), u
        return u


class _LivePlant:
    """The plant as plant_node holds it: the accepted model change is applied with
    ``configure`` at the first step at or after ``at`` [s] (a ``ValueError`` there is counted
    and the change not applied, as plant_node does)."""

    def __init__(self, plant: Any, at: float, changes: Mapping[str, Any]) -> None:
        self._p = plant
        self._at = at
        self._changes = dict(changes)
        self._t = 0.0
        self.output_names = plant.output_names
        self.input_names = plant.input_names
        self.disturbance_names = plant.disturbance_names
        self.not_applied: str | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._p, name)

    def outputs(self) -> np.ndarray:
        return self._p.outputs()

    def step(self, u: np.ndarray, d: np.ndarray, dt: float) -> None:
        if self._at is not None and self._t >= self._at - 1e-9:
            self._at = None
            if self._changes:
                try:
                    self._p.configure(**self._changes)
                except ValueError as exc:
                    self.not_applied = str(exc)
        self._t += dt
        self._p.step(u, d, dt)


def simulate(built: scenario.Built, live: Any = None, samples: int = SAMPLES) -> Run:
    """SETTLE + ``samples`` controller samples of the built loop (with the nodes' guards); the
    tracking error and outputs per sample. ``live``: a function wrapping (plant, controller)
    for a live change."""
    plant, controller = built.plant, built.controller
    if live is not None:
        plant, controller = live(plant, controller)
    ts_ns = to_ns(built.sample_time)
    cts_ns = to_ns(controller.sample_time)
    every = cts_ns // ts_ns
    duration = (SETTLE + samples) * cts_ns / NS_PER_S
    columns = loop_columns(plant, controller, built.reference)
    y_at = [columns.index(f'y.{n}') for n in controller.output_names]
    r_at = [columns.index(f'r.{n}') for n in controller.output_names]
    u_at = [columns.index(f'u.{n}') for n in controller.input_names]
    errors, outputs = [], []
    rows = iter_loop(plant, controller, built.reference, sample_time=built.sample_time,
                     duration=duration, noise=built.noise.sample_floats, guards=built.guards())
    last = time.monotonic()
    for k, row in enumerate(rows):
        now = time.monotonic()
        if now - last > TICK_SECONDS:
            return Run(broken=f'frozen: tick {k} took {now - last:.3g} s')
        last = now
        if k % every:
            continue
        values = np.array(row, dtype=float)
        if not np.all(np.isfinite(values)):
            bad = [c for c, v in zip(columns, row) if not math.isfinite(v)]
            return Run(broken=f'non-finite {bad} at t = {row[0]:g} s')
        errors.append(np.max(np.abs(values[y_at] - values[r_at])))
        outputs.append(np.max(np.abs(values[u_at])))
    return Run(np.array(errors), np.array(outputs))


def diverged(run: Run, default: Run) -> str | None:
    """The tracking error grows geometrically: in the last quarter of the run above
    DIVERGENCE times its second quarter and DIVERGENCE times above the default run's."""
    e = run.error[SETTLE:]
    n = len(e) // 4
    if n == 0:
        return None
    second, last = float(np.max(e[n:2 * n])), float(np.max(e[-n:]))
    reference = float(np.max(default.error)) + 1.0
    if last > DIVERGENCE * (second + reference) and last > DIVERGENCE * reference:
        return f'diverging: |y - r| {second:.3g} -> {last:.3g} (default run {reference:.3g})'
    return None


def _diverged(target: Target, run: Run, default: Run) -> str | None:
    """:func:`diverged` for a controller's parameters. A plant parameter changes the simulated
    physics: a loop it destabilises diverges as the physics says (the plants clip their states,
    so it stays finite), which is no fault of the node."""
    return diverged(run, default) if target.node == 'controller' else None


# -------------------------------------------------------------------------- the verdicts
@dataclass
class Verdict:
    """``refused`` with ``reason``, or accepted and ``broken`` (None: ran alive and finite);
    ``diverging``: accepted, finite, but the loop diverges geometrically (:func:`diverged`)."""

    refused: bool
    reason: str = ''
    broken: str | None = None
    diverging: str | None = None


def _refused(exc: BaseException) -> Verdict:
    reason = str(exc)
    if not reason or '\n' in reason:
        return Verdict(False, broken=f'refused without a one-line reason: {reason!r}')
    return Verdict(True, reason)


def _partner_sample_times(target: Target, changes: Mapping[str, Any],
                          sections: dict[str, dict[str, Any]]) -> None:
    """A sample time given to one node is given to the other too (the controller samples at
    plant ticks: a valid controller sample time becomes the plant's tick, a plant tick the
    controller's smallest multiple at or above its minimum)."""
    value = changes.get('sample_time')
    if not isinstance(value, (int, float)) or isinstance(value, bool) \
            or not 1e-6 <= value <= 3600.0:
        return                 # refused by the node's own sample_time spec
    if target.node == 'controller':
        sections['plant']['sample_time'] = float(value)
    else:
        minimum = next(s.min for s in node_specs.controller_specs(
            sections['controller']['controller']) if s.name == 'sample_time') or 0.0
        ts_ns = to_ns(float(value))
        if ts_ns <= 0:
            return
        k = max(1, math.ceil(minimum * NS_PER_S / ts_ns))
        if k * ts_ns / NS_PER_S * 1.0 > 3600.0:
            return
        sections['controller']['sample_time'] = k * ts_ns / NS_PER_S


def verdict(target: Target, changes: Mapping[str, Any], how: str) -> Verdict:
    """What the node does with ``changes`` given ``how`` ('file' or 'live')."""
    try:
        with _deadline(CASE_SECONDS):
            if how == 'file':
                return _file(target, changes)
            return _live(target, changes)
    except _Frozen:
        return Verdict(False, broken=f'frozen: one case took over {CASE_SECONDS} s')
    except Exception as exc:    # noqa: BLE001 - anything else would kill the node
        return Verdict(False, broken=f'{type(exc).__name__}: {exc}')


def _file(target: Target, changes: Mapping[str, Any]) -> Verdict:
    sections = {k: dict(v) for k, v in target.sections.items()}
    sections[target.node].update(changes)
    _partner_sample_times(target, changes, sections)
    try:
        built = scenario.build(sections)
    except (ConfigError, ValueError) as exc:
        return _refused(exc)
    broken = _timers(built.plant_setup.node)
    if broken:
        return Verdict(False, broken=broken)
    try:
        run = simulate(built)
    except (ConfigError, ValueError) as exc:    # wiring, sample times: the harness refuses
        return _refused(exc)
    return Verdict(False, broken=run.broken, diverging=run.broken or _diverged(
        target, run, default_run(freeze(_defaults_for(target, sections)))))


def _defaults_for(target: Target, sections: Mapping[str, Mapping[str, Any]]) -> dict:
    """The default loop at the sample times of ``sections`` (the reference run)."""
    base = {k: dict(v) for k, v in target.sections.items()}
    base['plant']['sample_time'] = sections['plant']['sample_time']
    if 'sample_time' in sections['controller']:
        base['controller']['sample_time'] = sections['controller']['sample_time']
        base['reference'] = dict(sections['reference'])
    try:
        scenario.build(base)
    except (ConfigError, ValueError):
        return {k: dict(v) for k, v in target.sections.items()}
    return base


def _timers(node: Any) -> str | None:
    """plant_node's timers from its accepted values must be representable (rclpy takes the
    period in int64 nanoseconds): the tick ``sample_time / real_time_factor``."""
    rtf = node.real_time_factor
    if rtf > 0:
        period = node.sample_time / rtf
        if not math.isfinite(period) or to_ns(period) >= INT64:
            return f'timer period {period!r} s from real_time_factor {rtf!r} cannot be made'
    return None


def _live(target: Target, changes: Mapping[str, Any]) -> Verdict:
    sections = {k: dict(v) for k, v in target.sections.items()}
    specs = {s.name: s for s in target.specs()}
    coerced = {}
    for name, value in changes.items():
        spec = specs.get(name)
        if spec is None:
            return Verdict(True, f'{name}: unknown parameter')
        if spec.read_only:
            return Verdict(True, f'{name}: read-only, set at start-up only')
        value = coerce(spec, value)
        reason = spec.check(value)
        if reason:
            return _refused(ConfigError(reason))
        coerced[name] = value
    built = scenario.build(sections)
    at = SETTLE * built.controller.sample_time
    if target.node == 'controller':
        return _live_controller(target, built, coerced, at)
    return _live_plant(target, built, coerced, at)


def _live_controller(target: Target, built: scenario.Built, changes: Mapping[str, Any],
                     at: float) -> Verdict:
    setup = built.controller_setup
    kind = setup.kind
    kind_names = {s.name for s in kind.specs()}
    current = setup.values()
    candidate = {**current, **changes}
    # pre-set: the derived values (not overriding the ones set in the request)
    if kind.derive is not None:
        try:
            derived = kind.derive({k: v for k, v in candidate.items() if k in kind_names})
        except ValueError:
            derived = {}
        candidate.update({k: v for k, v in derived.items() if k not in changes})
    # on-set: the whole candidate; post-set: the change, tried on the running controller
    try:
        new = scenario.controller_setup(candidate, given=frozenset(changes))
    except (ConfigError, ValueError) as exc:
        return _refused(exc)
    changed = frozenset(changes) & kind_names
    ranges = {k: v for k, v in changes.items() if k.startswith('range.')}
    if ranges:
        built.controller_setup = new      # range.* act on the next message

    wrapped_holder: list[_LiveController] = []

    def live(plant: Any, controller: Any) -> tuple[Any, Any]:
        def accept(t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray, u: np.ndarray
                   ) -> Any:
            if not changed:
                return None
            return controllers.prepare_change(kind, controller, new.settings, changed,
                                              trial=(t, y, r, d), u_last=u)
        wrapped_holder.append(_LiveController(controller, at, accept))
        return plant, wrapped_holder[0]
    run = simulate(built, live)
    wrapped = wrapped_holder[0]
    if wrapped.refused is not None:
        return _refused(ValueError(wrapped.refused))
    return Verdict(False, broken=run.broken, diverging=run.broken or _diverged(
        target, run, default_run(freeze(target.sections))))


def _live_plant(target: Target, built: scenario.Built, changes: Mapping[str, Any],
                at: float) -> Verdict:
    current = {**target.sections['plant']}
    for spec in target.specs():
        current.setdefault(spec.name, spec.default)
    candidate = {**current, **changes}
    try:
        setup = scenario.plant_setup(candidate)
        setup.build_noise(len(built.plant.output_names))
    except (ConfigError, ValueError) as exc:
        return _refused(exc)
    broken = _timers(setup.node)
    if broken:
        return Verdict(False, broken=broken)
    model_names = {s.name for s in setup.kind.specs()}
    model = {k: v for k, v in changes.items() if k in model_names}
    if 'noise_std' in changes:
        built.noise.set_std(changes['noise_std'])
    if any(k.startswith('range.') for k in changes):
        built.plant_setup = setup
    run = simulate(built, lambda plant, controller: (_LivePlant(plant, at, model), controller))
    return Verdict(False, broken=run.broken, diverging=run.broken or _diverged(
        target, run, default_run(freeze(target.sections))))


# ---------------------------------------------------------------------------- the values
SPECIAL_FLOATS = (0.0, -0.0, 5e-324, -5e-324, 1e-320, 2.2250738585072014e-308, 1e-300,
                  -1e-300, 1e-170, 1e-160, 1e-154, 1e-30, 1e-12, 1e-9, 1e-6, 1e-3, -1.0, 1.0,
                  1e6, 1e9, 1e12, 1e154, -1e154, 1e300, -1e300, 1e308, -1e308,
                  1.7976931348623157e308, math.nan, math.inf, -math.inf)


def value_strategy(spec: ParamSpec) -> Any:
    """Values for ``spec``: special floats (denormals, underflows, huge, ±inf, nan), any
    float, the bounds and their neighbours, scaled defaults, integers beyond int64, and values
    of the wrong type."""
    from hypothesis import strategies as st
    default = spec.default
    wrong = st.one_of(st.text(max_size=8), st.booleans(), st.none(),
                      st.lists(st.floats(), max_size=3), st.dictionaries(st.text(max_size=3),
                                                                         st.integers(), max_size=2))
    edges = [v for v in (spec.min, spec.max) if v is not None]
    edges += [math.nextafter(v, -math.inf) for v in edges] + [
        math.nextafter(v, math.inf) for v in edges]
    tiny = getattr(spec, 'tiny', None)
    if tiny:
        edges += [tiny, math.nextafter(tiny, 0.0)]
    floats = st.one_of(
        st.sampled_from(SPECIAL_FLOATS),
        st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True),
        st.sampled_from(edges or [0.0]),
        st.floats(min_value=float(spec.min) if spec.min is not None else -1e12,
                  max_value=float(spec.max) if spec.max is not None else 1e12))
    ints = st.one_of(st.integers(min_value=-2 ** 70, max_value=2 ** 70),
                     st.sampled_from((0, -1, 1, INT64 - 1, -INT64, INT64, 2 ** 64)))
    if isinstance(default, bool):
        return st.one_of(st.booleans(), ints, floats, wrong)
    if isinstance(default, str):
        choices = st.sampled_from(spec.choices) if spec.choices else st.text(max_size=12)
        return st.one_of(choices, st.text(max_size=12), floats, wrong)
    if isinstance(default, int):
        near = [int(v) for v in edges if math.isfinite(v) and abs(v) < 2 ** 70]
        return st.one_of(ints, st.sampled_from(near or [0]), floats, wrong)
    if isinstance(default, float):
        scaled = st.sampled_from([default * f for f in (-1.0, 0.1, 1e-3, 10.0, 1e3, 1e6)])
        return st.one_of(floats, scaled, ints, wrong)
    if isinstance(default, list) and default and isinstance(default[0], str):
        names = st.sampled_from(sorted({*default, 'y', 'u', 'h', 'T_out', 'F_H', 'F_Cin', ''}))
        return st.one_of(st.lists(names, max_size=3), st.lists(st.text(max_size=4), max_size=3),
                         floats, wrong)
    if isinstance(default, list):
        item = st.one_of(floats, st.sampled_from(default))
        return st.one_of(st.lists(item, min_size=0, max_size=4),
                         st.lists(st.sampled_from(SPECIAL_FLOATS), min_size=len(default),
                                  max_size=len(default)),
                         floats, ints, wrong)
    return wrong


def change_strategy(target: Target) -> Any:
    """One to three parameters of ``target``'s node with hostile values (the node's own kind
    selector excluded: that is the kind)."""
    from hypothesis import strategies as st
    specs = [s for s in target.specs() if s.name not in ('plant', 'controller')]

    def values(chosen: list[ParamSpec]) -> Any:
        own = st.fixed_dictionaries({s.name: value_strategy(s) for s in chosen})
        same = st.sampled_from(SPECIAL_FLOATS).map(lambda v: {s.name: v for s in chosen})
        return st.one_of(own, same)     # same: e.g. ti = td = 1e-170 (their product underflows)
    return st.lists(st.sampled_from(specs), min_size=1, max_size=3,
                    unique_by=lambda s: s.name).flatmap(values)
