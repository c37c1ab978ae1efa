"""The controller node's parameters: the kind from the overrides, the cross-check of a change
(the candidate controller tried from the last sample), derived values, and a change taking
effect at a step, bumplessly (docs/nodes.md, "controller_node")."""
from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from tank_control.core import node_specs, ranges
from tank_control.core.control.kinds import registry
from tank_control.core.params import ConfigError
from tank_control.core.scenario import controller_setup
from tank_control.nodes.controller_reports import ControllerReports
from tank_control.nodes import live_derive
from tank_control.nodes.live_derive import LiveDerive
from tank_control.nodes.live_rebuild import LiveRebuild
from tank_control.nodes.params import ParameterError


class ControllerParams(ControllerReports):
    """Parameter handling of ``controller_node`` (a base class of ``ControllerNode``)."""

    _kind_names: frozenset[str]
    _prepared: tuple[registry.PreparedChange, int] | None
    _last_sample_io: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None
    #: wall mode: a change of the kind's ``slow`` parameters is built off the sampling path
    _wall = False
    _rebuild: LiveRebuild | None = None     # such a change being built (nodes/live_rebuild.py)
    _derivation: LiveDerive | None = None   # a costly rule's design running (live_derive.py)

    def _kind_from_overrides(self) -> str:
        override = getattr(self, '_parameter_overrides', {}).get('controller')
        try:
            return node_specs.kind_of('controller', {} if override is None
                                      else {'controller': override.value})
        except ConfigError as exc:
            raise ParameterError(str(exc)) from None

    def _override_values(self) -> dict[str, Any]:
        return {name: p.value for name, p in getattr(self, '_parameter_overrides', {}).items()}

    def _cross_check(self, values: Mapping[str, Any], changed: frozenset[str]) -> str | None:
        # the node's own results (tuned gains, an identified model) are not a user's change:
        # they are checked as values, not against a guard on changes (robustness.ms_max)
        writing = getattr(self, '_params', None) is not None and self._params.writing
        given = frozenset() if writing else changed
        deferred = self._defers(values, changed, writing)
        try:
            setup = controller_setup(live_derive.without_design(values) if deferred else values,
                                     given=given)
        except ConfigError as exc:
            return str(exc)
        mine = changed & self._kind_names
        if writing or not mine or getattr(self, '_controller', None) is None:
            return None
        if deferred:
            # wall: a costly rule's design runs in the worker; the running law samples on
            design = live_derive.design_inputs(mine)
            if design:
                self._derive_off_path(values, design)
            mine -= design
            if not mine:
                return None
        # a user's change of the controller: build the candidate now and try it from the last
        # sample (the derived quantities must give finite outputs); it takes effect next sample
        if self._prepared is not None and self._prepared[1] == self._gen:
            mine |= self._prepared[0].changed          # accepted earlier, not applied yet
        if self._wall and (self._rebuild is not None or mine & set(self._kind.slow)):
            self._offload(setup.settings, frozenset(mine))
            return None
        try:
            prepared = registry.prepare_change(
                self._kind, self._controller, setup.settings, frozenset(mine),
                trial=self._last_sample_io, u_last=self._u)
        except ValueError as exc:
            return str(exc)
        self._prepared = (prepared, self._gen)
        return None

    def _defers(self, values: Mapping[str, Any], changed: frozenset[str], writing: bool) -> bool:
        """wall: the rule's design for ``values`` is left to the worker (a user's change that
        needs a costly rule's new design, or any change while one is running: the node's own
        results included)."""
        return (self._wall and self._kind.derive is not None
                and (self._derivation is not None
                     or (not writing and live_derive.costly(values, changed))))

    def _derive_off_path(self, values: Mapping[str, Any], design: frozenset[str]) -> None:
        """Start the design of ``values`` in the worker (a design still running: its result is
        superseded; the set-back values stay the running law's)."""
        old = {n: v for n, v in self._params.values.items() if n in design}
        if self._derivation is not None:
            old.update(self._derivation.old)
            design |= self._derivation.changed
        self._derivation = LiveDerive(self._kind, frozenset(self._kind_names), values, design,
                                      old)

    def _take_derivation(self) -> list[str]:
        """wall: once the worker's design is ready, its gains are written as parameters and
        taken with the changed design inputs (their names, to apply at this sample); a failed
        design sets the inputs back and says why."""
        derivation = self._derivation
        if derivation is None or not derivation.done():
            return []
        self._derivation = None
        cause = 'derived from ' + ', '.join(sorted(derivation.changed))
        try:
            gains = derivation.gains()
            current = self._params.values
            gains = {k: v for k, v in gains.items() if current.get(k) != v}
            result = self._params.write(gains, source=cause) if gains else None
            if result is not None and not result.successful:
                raise ValueError(result.reason)
        except ValueError as exc:
            self._set_back(derivation.old, f'tuning design failed ({exc}); the running gains '
                           'are kept', 'the tuning design failed')
            return []
        return sorted(set(gains) | derivation.changed)

    def _set_back(self, old: Mapping[str, Any], what: str, source: str) -> None:
        """A change made off the sampling path failed: count it, say ``what`` happened and
        which values were set back (log, /diagnostics), and write ``old`` back."""
        self.counters['update_errors'] += 1
        back = ', '.join(f'{n} set back to {v!r}' for n, v in sorted(old.items()))
        self._update_error = f'{what} and {back}'
        self.get_logger().error(self._update_error)
        self._params.write(old, source=source)
        self._publish_diagnostics()

    def _mark_clock(self, controller: Any) -> Any:
        """A controller with heavy work of its own (the relay auto-tuner's design) does it
        off the sampling path in wall mode (its ``wall_clock``)."""
        if hasattr(controller, 'wall_clock'):
            controller.wall_clock = self._wall
        return controller

    def _offload(self, settings: Any, mine: frozenset[str]) -> None:
        """Build the accepted change in the worker thread from a copy of the running
        controller (with a change still being built: both together, from the running one)."""
        old = {n: v for n, v in self._params.values.items() if n in mine}
        if self._rebuild is not None:
            old.update(self._rebuild.old)              # the running law's, not the pending's
            mine |= self._rebuild.changed
        self._rebuild = LiveRebuild(self._kind, copy.deepcopy(self._controller),
                                    settings, mine, old, self._gen, self._last_sample_io,
                                    None if self._u is None else self._u.copy())
        self._prepared = None

    def _switch(self, gen: int, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray
                ) -> np.ndarray | None:
        """wall: the first sample after a change built off the sampling path is ready takes
        it (its output), or keeps the running law when it was refused; None: nothing ready."""
        rebuild = self._rebuild
        if rebuild is None or not rebuild.done():
            return None
        self._rebuild = None
        try:
            rebuild.prepared()
        except ValueError as exc:
            self._set_back(rebuild.old, f'parameter change refused when built ({exc}); the '
                           'running law is kept', 'the change could not be built')
            return None
        self._controller, u = rebuild.switch(self._controller, gen, t, y, r, d)
        self._mark_clock(self._controller)
        self._update_error = ''
        return u

    def _on_params_set(self, parameters: list) -> None:
        """Accepted ``range.*`` changes act at once (on the next message)."""
        given = {p.name: p.value for p in parameters if p.name.startswith(ranges.PREFIX)}
        if given:
            values = {**self._params.values, **given}
            self._ranges = ranges.ranges_from(values, tuple(self._ranges.bounds))

    def _derive(self, values: Mapping[str, Any], changed: frozenset[str]) -> dict[str, Any]:
        extra = {}
        if self._kind.derive is not None:
            kind_values = {k: v for k, v in values.items() if k in self._kind_names}
            writing = getattr(self, '_params', None) is not None and self._params.writing
            if not self._defers(values, changed, writing):   # wall: the worker designs
                extra = {k: v for k, v in self._kind.derive(kind_values).items()
                         if k not in changed}
        # auto → manual without a manual_output: keep the current output (bumpless)
        if ('mode' in changed and values.get('mode') == 'manual' and 'manual_output' not in changed
                and isinstance(values.get('manual_output'), float) and self._u is not None
                and self._u.size == 1):
            lo, hi = values.get('u_min', -math.inf), values.get('u_max', math.inf)
            extra['manual_output'] = float(min(max(self._u[0], lo), hi))
        return extra

    def _step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        """One controller step; accepted parameter changes take effect at it, bumplessly."""
        held = self._derivation.changed if self._derivation is not None else frozenset()
        derived = self._take_derivation() if self._derivation is not None else []
        changed = [name for name in self._params.take_pending() if name in self._kind_names
                   and (self._rebuild is None or name not in self._rebuild.changed)
                   and name not in held and name not in derived] + derived
        prepared, self._prepared = self._prepared, None
        if derived:
            prepared = None          # made anew with the derived gains
        gen, self._gen = self._gen, self._gen + 1
        switched = self._switch(gen, t, y, r, d)
        if switched is not None:
            return switched
        if changed:
            try:
                # the candidate checked on acceptance, unless it is a copy of a running
                # controller that has stepped or reset since (then it is made anew)
                if prepared is None or (prepared[0].in_place and prepared[1] != gen):
                    values = self._params.values
                    if self._derivation is not None:      # the design is not ready yet
                        values = live_derive.without_design(values)
                    settings = controller_setup(values, given=()).settings
                    prepared = (registry.prepare_change(self._kind, self._controller, settings,
                                                        frozenset(changed)), gen)
                self._controller, u = prepared[0].take_effect(self._controller, t, y, r, d)
                self._mark_clock(self._controller)
                self._update_error = ''
                return u
            except ValueError as exc:    # checked before acceptance; never expected
                self.counters['update_errors'] += 1
                self._update_error = f'parameter change could not be applied: {exc}'
                self.get_logger().error(self._update_error)
                self._publish_diagnostics()
        return np.asarray(self._controller.step(t, y, r, d), dtype=float)

