"""What every sampled SISO control law here shares ([Viteckova] eq. 19 PID, [Ikonen] §1.2–1.4 lead-lag).

:class:`SisoLaw`: manual/auto with bumpless transfer, bumpless ``reset``, output limits, hold of
the last output on a non-finite input, ``direct_action``, the forward-Euler integral in output
units with anti-windup, operator actions and status. The law itself (its terms and filter
state) is the subclass's. :class:`SisoController` puts a law behind the Controller protocol of
core/interfaces.py. Units: outputs in u units, times in s.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import fields, replace
from typing import Any, ClassVar, Generic, Protocol, TypeVar

import numpy as np



class LawConfig(Protocol):
    """What the shared part reads of a law's configuration (a frozen dataclass)."""

    __dataclass_fields__: ClassVar[dict[str, Any]]

    @property
    def ti(self) -> float: ...                       # integral time [s]; inf: none

    @property
    def tracking_time(self) -> float | None: ...     # anti-windup Tt [s]; None: the law's

    @property
    def sample_time(self) -> float: ...              # [s]

    @property
    def u_min(self) -> float: ...

    @property
    def u_max(self) -> float: ...

    @property
    def anti_windup(self) -> str: ...                # core/control/pid.ANTI_WINDUP_CHOICES


ConfigT = TypeVar('ConfigT', bound=LawConfig)
_FLOAT64 = np.dtype(np.float64)
LawT = TypeVar('LawT', bound='SisoLaw[Any]')


class SisoLaw(Generic[ConfigT]):
    """Base of a sampled SISO law ``u = law(r, y)`` with an integral ``I`` [u units] and one
    low-pass state ``x`` [units of its error].

    A subclass validates its configuration (:meth:`_check`), puts the law at rest
    (:meth:`_rest`), evaluates one automatic sample (:meth:`_update_auto`, finishing with
    :meth:`_accept` and :meth:`_apply`), absorbs gain changes (:meth:`_retune`) and names its
    terms (:meth:`_terms`). The configuration has at least ``kp``, ``ti``, ``sample_time``,
    ``u_min``, ``u_max``, ``anti_windup``, ``tracking_time`` and ``direct_action``.
    """

    unknown_setting = 'unknown setting'
    """How ``set_gains`` calls a name that is no field of the configuration."""

    def __init__(self, config: ConfigT) -> None:
        self._check(config)
        self._set_config(replace(config))
        self._mode = 'auto'
        self._manual_u: float | None = None
        self._x = 0.0            # low-pass state of the law [units of its error]
        self._i = 0.0            # integral [u units]
        self._u: float | None = None   # last applied output
        self._v = 0.0            # last unlimited output
        self._i_out = 0.0        # integral used by the last sample
        self._last: tuple[float, float] | None = None   # last finite (r, y)
        self._initialised = False
        self._fault = False
        self._saturated = False
        self._aw_active = False

    # ------------------------------------------------------------- subclass
    def _check(self, config: ConfigT) -> None:
        """Raise ValueError naming the parameter if ``config`` is invalid."""
        raise NotImplementedError

    def _rest(self, r: float, y: float) -> float:
        """Set the law's state to rest at (r, y) (no kick at the next sample); return the
        output without the integral there."""
        raise NotImplementedError

    def _update_auto(self, r: float, y: float) -> float:
        """One automatic sample (finite r, y)."""
        raise NotImplementedError

    def _retune(self, old: ConfigT, new: ConfigT, r: float, y: float) -> None:
        """Absorb the change ``old`` → ``new`` at the last inputs (r, y) into the state."""
        raise NotImplementedError

    def _terms(self) -> dict[str, float]:
        """The law's terms of the last sample, for :attr:`status`."""
        raise NotImplementedError

    def _flags(self) -> dict[str, bool]:
        """Further flags of the last sample, for :attr:`status` (after ``saturated``)."""
        return {}

    def _default_tracking_time(self) -> float:
        """Back-calculation tracking time Tt [s] when ``tracking_time`` is None."""
        raise NotImplementedError

    def _set_config(self, cfg: ConfigT) -> None:
        """Take ``cfg`` (validated) into use with the constants every sample needs: the signed
        gain, whether there is integral action and the anti-windup tracking time Tt [s]."""
        self._cfg: ConfigT = cfg
        self._k = self._gain()
        self._has_integral = math.isfinite(self._cfg.ti)
        self._tt = (self._cfg.tracking_time or self._default_tracking_time()
                    if self._has_integral else math.inf)
        # back-calculation gain min(h/Tt, 1); Tt = 0 (an underflow of √(ti·td)): 1, at the sample
        self._aw_gain = min(self._cfg.sample_time / self._tt, 1.0) if self._tt else 1.0

    # ----------------------------------------------------------------- state
    @property
    def config(self) -> ConfigT:
        """A copy of the current settings."""
        return replace(self._cfg)

    @property
    def output(self) -> float | None:
        """Last applied output (None before the first sample)."""
        return self._u

    @property
    def mode(self) -> str:
        return self._mode

    @property
    def limits(self) -> tuple[float, float]:
        """The output limits ``(u_min, u_max)`` in force [u units] (without copying the
        configuration as :attr:`config` does)."""
        return self._cfg.u_min, self._cfg.u_max

    @property
    def status(self) -> dict[str, Any]:
        """mode, saturated, the subclass's flags, anti_windup_active, input_fault, the
        subclass's terms, the unlimited ``v`` and applied ``u`` of the last sample."""
        status: dict[str, Any] = {'mode': self._mode, 'saturated': self._saturated}
        status.update(self._flags())
        status['anti_windup_active'] = self._aw_active
        status['input_fault'] = self._fault
        status.update(self._terms())
        status['v'] = self._v
        status['u'] = math.nan if self._u is None else self._u
        return status

    def _gain(self, cfg: ConfigT | None = None) -> float:
        c: Any = cfg or self._cfg
        return -c.kp if c.direct_action else c.kp

    def _clip(self, u: float) -> float:
        return min(max(u, self._cfg.u_min), self._cfg.u_max)

    def _limit(self, v: float) -> float:
        """The output applied for the wanted ``v`` (here the limits)."""
        return self._clip(v)

    def _hold_output(self) -> float:
        return self._u if self._u is not None else self._clip(0.0)

    # ------------------------------------------------------------- operation
    def reset(self, r: float, y: float, u: float) -> None:
        """Initialise bumplessly: with the same ``r`` and ``y`` the next ``update`` returns
        ``u`` (clipped to the limits). No kick."""
        for name, value in (('r', r), ('y', y), ('u', u)):
            if not math.isfinite(value):
                raise ValueError(f'reset: {name} = {value!r} is not finite')
        u = self._clip(float(u))
        self._track(float(r), float(y), u)
        self._u = u
        self._v = u
        self._fault = False
        if self._mode == 'manual':
            self._manual_u = u

    def _track(self, r: float, y: float, u: float) -> None:
        """Set the states so that the output at (r, y) is ``u`` with the law at rest."""
        self._i = u - self._rest(r, y)
        self._i_out = self._i
        self._last = (r, y)
        self._initialised = True

    def update(self, r: float, y: float) -> float:
        """One sample: setpoint ``r`` and measurement ``y`` → output ``u``."""
        if not (math.isfinite(r) and math.isfinite(y)):
            self._fault = True
            return self._hold_output()
        r, y = float(r), float(y)
        if self._fault:
            self._fault = False
            self._track(r, y, self._hold_output())
        if not self._initialised:
            self._track(r, y, 0.0)
            self._i = self._i_out = 0.0
        if self._mode == 'manual':
            return self._update_manual(r, y)
        return self._update_auto(r, y)

    def _update_manual(self, r: float, y: float) -> float:
        target = self._manual_u if self._manual_u is not None else self._hold_output()
        u = self._limit(target)
        self._track(r, y, u)
        self._v = u
        self._u = u
        self._saturated = u != target
        self._aw_active = False
        return u

    def _accept(self, v: float, x_next: float) -> bool:
        """Store the next low-pass state ``x_next`` if it and the unlimited output ``v`` are
        finite; else (overflow from absurd inputs) flag an input fault and keep the state."""
        if not (math.isfinite(v) and math.isfinite(x_next)):
            self._fault = True
            return False
        self._x = x_next
        return True

    def _apply(self, r: float, y: float, v: float, k: float, e: float) -> float:
        """Limit ``v``, integrate the error ``e`` with the gain ``k`` and return the output."""
        u = self._limit(v)
        self._v = v
        self._i_out = self._i
        self._integrate(k, e, u, v)
        self._saturated = u != v
        self._u = u
        self._last = (r, y)
        return u

    def _integrate(self, k: float, e: float, u: float, v: float) -> None:
        """Forward Euler ``I ← I + k·h/ti·e`` ([Viteckova] eq. 19) with anti-windup: back-calculation
        ``+ min(h/Tt, 1)·(u − v)`` (h/Tt ≤ 1: stable for any Tt), conditional integration
        (no step that drives further into the limit), or none. ``ti = inf``: no integral."""
        cfg = self._cfg
        self._aw_active = False
        if not self._has_integral:
            return
        h = cfg.sample_time
        di = k * h / cfg.ti * e
        if cfg.anti_windup == 'back_calculation':
            self._i += di + self._aw_gain * (u - v)
            self._aw_active = u != v
        elif cfg.anti_windup == 'conditional_integration':
            if (v > u and di > 0.0) or (v < u and di < 0.0):
                self._aw_active = True
            else:
                self._i += di
        else:
            self._i += di

    # ------------------------------------------------------ operator actions
    def set_gains(self, **changes: Any) -> None:
        """Change any configuration field (by field name) bumplessly: at unchanged inputs the
        next output is the one the old settings would give. ``ValueError`` naming the
        parameter leaves the law untouched."""
        known = {f.name for f in fields(self._cfg)}
        for name in changes:
            if name not in known:
                raise ValueError(f'{name}: {self.unknown_setting}; allowed '
                                 + ', '.join(sorted(known)))
        new = replace(self._cfg, **changes)
        self._check(new)
        if self._initialised and self._last is not None:
            self._retune(self._cfg, new, *self._last)
        self._set_config(new)

    def set_manual(self, u: float | None = None) -> None:
        """Switch to manual: the output becomes ``u`` (limited) from the next sample; without
        ``u`` the last output is held (bumpless)."""
        if u is not None and not math.isfinite(u):
            raise ValueError(f'manual_output: {u!r} is not finite')
        self._manual_u = self._hold_output() if u is None else float(u)
        self._mode = 'manual'

    def set_auto(self) -> None:
        """Switch to automatic; the next output continues from the last one."""
        if self._mode == 'manual' and self._last is not None and self._u is not None:
            self._track(*self._last, self._u)
        self._mode = 'auto'


class SisoController(Generic[LawT]):
    """A :class:`SisoLaw` behind the Controller protocol of core/interfaces.py.

    Reads the measured channel ``output_name`` and its setpoint, writes the manipulated
    channel ``input_name``. ``reset(y, u)`` is completed at the first ``step`` (which knows
    ``r``), so that step returns ``u`` exactly.
    """

    disturbance_names: tuple[str, ...] = ()
    law_name = 'law'
    """Named in the message about a vector of the wrong size."""

    def __init__(self, law: LawT, output_name: str = 'y', input_name: str = 'u') -> None:
        self._law = law
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self._pending: float | None = None

    @property
    def sample_time(self) -> float:
        return self._law.config.sample_time

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        self._scalar(y, 'y')
        u0 = self._scalar(u, 'u')
        if not math.isfinite(u0):
            raise ValueError(f'reset: u = {u0!r} is not finite')
        self._pending = u0

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        if (type(y) is np.ndarray and type(r) is np.ndarray and y.shape == r.shape == (1,)
                and y.dtype is r.dtype is _FLOAT64):
            y0, r0 = y.item(), r.item()                # what _scalar gives, without the calls
        else:
            y0, r0 = self._scalar(y, 'y'), self._scalar(r, 'r')
        if self._pending is not None and math.isfinite(y0) and math.isfinite(r0):
            self._law.reset(r0, y0, self._pending)
            self._pending = None
        return np.array([self._law.update(r0, y0)], dtype=float)

    @property
    def law(self) -> LawT:
        """The control law in use (its live settings, mode and state)."""
        return self._law

    @property
    def status(self) -> Mapping[str, Any]:
        return self._law.status

    def _scalar(self, value: Any, name: str) -> float:
        if type(value) is np.ndarray and value.shape == (1,) and value.dtype is _FLOAT64:
            return value.item()
        arr = np.asarray(value, dtype=float).reshape(-1)
        if arr.size != 1:
            raise ValueError(f'{name}: expected 1 value for a SISO {self.law_name}, '
                             f'got {arr.size}')
        return float(arr[0])
