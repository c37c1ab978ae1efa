"""Multivariable auto-tuning of the two-loop PI of the mixing tank ([Precup2013] §3.7).

A :class:`MimoAutotuner` is the :class:`~tank_control.core.control.multiloop.TwoLoopPi` with an
auto-tuning test; idle it is that controller exactly. ``autotune.mode``:

* ``relay`` — the sequential relay test ([Precup2013] §3.7.1, Fig. 3.8): after settling under the running
  PI, a relay on loop h with loop T held (open) gives the ultimate point of ``H_P11``; loop h is
  placed (eqs. 3.7.6–3.7.7) and closed; a relay on loop T gives the ultimate point of its
  equivalent process ``H_P2`` (eq. 3.7.5), loop T is placed and closed; a relay on loop h again
  gives ``H_P1`` (eq. 3.7.4) and loop h is placed once more. With a decoupler the relays act on
  the PI outputs ``v`` before it, so the equivalent processes are those of the decoupled tank.
  Each relay is a :class:`~tank_control.core.control.relay_autotune.RelayAutotuner` (its cycle
  detection, stationarity check and first-harmonic ultimate point).
* ``model_zn`` — the same three placements on the tank linearised at [Michalski2021]'s operating point with
  its delays (``multiloop_tuning.multiloop_design``), no experiment.
* ``model_ls`` — [Precup2013] eqs. 3.7.8–3.7.10: the two-loop PI (with its decoupler) fitted by least
  squares to the decoupled second-order-plus-dead-time target on that model.

States (``autotune.state``): ``idle → settling → relay ⇄ measuring → tuned → running``, or
``proposed`` with ``autotune.apply`` preview; ``failed`` / ``aborted`` put the gains from before
the test back, bumplessly; ``reverted`` after ``revert_gains``. During the relay test the
measured-disturbance feedforward (if any) is off and resumes with the PI; a test is refused
while a gain schedule is active. Units: cm, °C, cm³/s, s.
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tank_control.core.control.autotune_machine import AutotuneMachine
from tank_control.core.control.multiloop import D21Filter, TwoLoopPi, TwoLoopPiConfig, _d21_gain
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import AutotuneConfig, RelayAutotuner, autotune_param
from tank_control.core.params import check_config
from tank_control.core.tuning import multiloop_tuning as mlt

MODES = ('none', 'relay', 'model_zn', 'model_ls')
RULES = ('zn', 'point')
TESTING = ('settling', 'relay', 'measuring')
LOOPS = ('h', 'T_out')
STAGES = ((0, 'loop h, loop T held'), (1, 'loop T, loop h closed'), (0, 'loop h, loop T closed'))
"""The sequential relay test: (loop, what the other loop does) per stage."""
_BIG = 1e12


_m = autotune_param


@dataclass(frozen=True)
class MimoAutotuneConfig:
    """Settings of the multivariable auto-tuning of ``two_loop_pi`` ([Precup2013] §3.7)."""

    mode: str = _m('none', 'multivariable auto-tuning: none; relay (sequential relay test on the '
                   'running loop, [Precup2013] §3.7.1); model_zn (the same placements on the tank '
                   'linearised at [Michalski2021]\'s operating point with its delays); model_ls (two-loop PI '
                   'by least squares on a decoupled target, [Precup2013] eqs. 3.7.8–3.7.10)', 'mode',
                   choices=MODES, read_only=True, source='[Precup2013] §3.7')
    rule: str = _m('point', 'loop point each loop is placed at ([Precup2013] eqs. 3.7.6–3.7.7): zn = '
                   'the Ziegler–Nichols PI (0.45·Ku, Ti = Tu/1.2; r_b 0.458, φ_b −10.8°), point '
                   '= autotune.loop_gain, autotune.loop_phase (default 0.3, −8°: kR = 0.297·Ku, '
                   'Ti = 1.13·Tu, what the decoupled tank takes)', 'rule', choices=RULES)
    loop_gain: float = _m(0.3, 'rule point: |H_0(jω_u)| = r_b of the loop at the ultimate '
                          'frequency of its equivalent process', 'loop_gain', unit='-',
                          min=1e-3, max=0.99, source='[Precup2013] eq. 3.7.7')
    loop_phase: float = _m(-8.0, 'rule point: φ_b, the loop point at −180° + φ_b (a PI needs '
                           'φ_b < 0)', 'loop_phase', unit='deg', min=-89.0, max=-0.01,
                           source='[Precup2013] eq. 3.7.7')
    relay_amplitude_h: float = _m(2.0, 'relay amplitude on loop h (on the PI output v_h before '
                                  'the decoupler)', 'relay_amplitude_h', unit='cm³/s',
                                  min=1e-6, max=1e4)
    relay_amplitude_T: float = _m(5.0, 'relay amplitude on loop T_out (on v_T)',
                                  'relay_amplitude_T', unit='cm³/s', min=1e-6, max=1e4)
    hysteresis_h: float = _m(3.0, 'relay hysteresis on loop h; behind the decoupler a few cm '
                             'slow the relay to the delayed cold-flow path (a small one cycles '
                             'at the sampling limit on F_H alone)', 'hysteresis_h', unit='cm',
                             min=0.0, max=100.0)
    hysteresis_T: float = _m(0.02, 'relay hysteresis on loop T_out', 'hysteresis_T',
                             unit='°C', min=0.0, max=100.0)
    ls_omega0_h: float = _m(0.004, 'model_ls: natural frequency ω0 of the level target',
                            'ls_omega0_h', unit='rad/s', min=1e-6, max=10.0,
                            source='[Precup2013] eq. 3.7.9')
    ls_omega0_T: float = _m(0.003, 'model_ls: natural frequency ω0 of the T_out target',
                            'ls_omega0_T', unit='rad/s', min=1e-6, max=10.0,
                            source='[Precup2013] eq. 3.7.9')
    ls_xi: float = _m(1.5, 'model_ls: damping ξ of both targets', 'ls_xi', unit='-', min=0.1,
                      max=5.0, source='[Precup2013] eq. 3.7.9')
    ls_dead_time_T: float = _m(120.0, 'model_ls: dead time Tm of the T_out target (the level '
                               'target has none: F_H acts at once)', 'ls_dead_time_T', unit='s',
                               min=0.0, max=1e4, source='[Precup2013] eq. 3.7.9')
    ls_omega_max: float = _m(0.02, 'model_ls: highest fitted frequency (40 points from '
                             'ls_omega_max/1000 up, logarithmic)', 'ls_omega_max',
                             unit='rad/s', min=1e-5, max=10.0)

    def reason(self) -> str | None:
        return None

    @property
    def loop_point(self) -> tuple[float, float]:
        """``(r_b, φ_b [rad])`` of the rule."""
        if self.rule == 'zn':
            return mlt.zn_point()
        return self.loop_gain, math.radians(self.loop_phase)


@dataclass(frozen=True)
class MimoAutotuneResults:
    """What the multivariable tuning found (read-only, written by the node)."""

    relay_loop: str = _m('none', 'loop the relay acts on now (sequential relay test)',
                         'relay_loop', choices=('none',) + LOOPS, read_only=True)
    relay_stage: int = _m(0, 'stage of the sequential relay test: 1 loop h (T held), 2 loop T '
                          '(h closed), 3 loop h (T closed); 0 none', 'relay_stage', min=0,
                          max=3, read_only=True)
    ku_h: float = _m(0.0, 'ultimate gain of loop h\'s equivalent process (last placement)',
                     'ku_h', unit='cm³/s per cm', min=0.0, max=_BIG, read_only=True)
    tu_h: float = _m(0.0, 'ultimate period of loop h\'s equivalent process', 'tu_h', unit='s',
                     min=0.0, max=_BIG, read_only=True)
    ku_T: float = _m(0.0, 'ultimate gain of loop T_out\'s equivalent process', 'ku_T',
                     unit='cm³/s per °C', min=0.0, max=_BIG, read_only=True)
    tu_T: float = _m(0.0, 'ultimate period of loop T_out\'s equivalent process', 'tu_T',
                     unit='s', min=0.0, max=_BIG, read_only=True)
    ku_h_open: float = _m(0.0, 'stage 1: ultimate gain of loop h with loop T open',
                          'ku_h_open', unit='cm³/s per cm', min=0.0, max=_BIG, read_only=True)
    tu_h_open: float = _m(0.0, 'stage 1: ultimate period of loop h with loop T open',
                          'tu_h_open', unit='s', min=0.0, max=_BIG, read_only=True)
    proposed_kp_h: float = _m(0.0, 'designed kp of loop h', 'proposed_kp_h', min=-_BIG,
                              max=_BIG, read_only=True)
    proposed_ki_h: float = _m(0.0, 'designed ki of loop h', 'proposed_ki_h', min=-_BIG,
                              max=_BIG, read_only=True)
    proposed_kp_T: float = _m(0.0, 'designed kp of loop T_out', 'proposed_kp_T', min=-_BIG,
                              max=_BIG, read_only=True)
    proposed_ki_T: float = _m(0.0, 'designed ki of loop T_out', 'proposed_ki_T', min=-_BIG,
                              max=_BIG, read_only=True)
    ls_residual: float = _m(0.0, 'model_ls: relative residual of the fit of [Precup2013] eq. 3.7.10',
                            'ls_residual', min=0.0, max=_BIG, read_only=True)


RELAY_SETTINGS = ('settle_time', 'settle_band', 'settle_timeout', 'timeout', 'min_cycles',
                  'stationarity_tol', 'max_amplitude', 'apply', 'apply_time', 'start_time',
                  'method')
"""The ``autotune.*`` settings of the SISO tuner (:class:`AutotuneConfig`) this one uses."""


def model_response(cfg: TwoLoopPiConfig) -> tuple[mlt.Response, mlt.Response]:
    """``(H_P·D, D)``: the tank linearised at [Michalski2021]'s operating point (delays included) seen
    through the decoupler of ``cfg``, and the decoupler."""
    from tank_control.core.plants.mixing_tank import OPERATING_POINT, MixingTankConfig
    tank = MixingTankConfig(T_op=OPERATING_POINT.T)        # the exact steady state 2115/63

    def decoupler(w: float) -> np.ndarray:
        return mlt.decoupler_response(cfg.decoupling, cfg.d12, cfg.d21, cfg.sample_time, w)

    def process(w: float) -> np.ndarray:
        return mlt.tank_frequency_response(tank, w) @ decoupler(w)

    return process, decoupler


def model_design(cfg: TwoLoopPiConfig, mimo: MimoAutotuneConfig
                 ) -> tuple[tuple[mlt.PiGains, mlt.PiGains], dict[str, float]]:
    """The gains of ``model_zn`` / ``model_ls`` for the running decoupler, and what the
    design found (ultimate points, residual)."""
    process, decoupler = model_response(cfg)
    if mimo.mode == 'model_zn':
        r_b, phi_b = mimo.loop_point
        d = mlt.multiloop_design(process, r_b, phi_b, 1e-5, math.pi / cfg.sample_time)
        return d.loops, {'ku_h': d.ku[0], 'tu_h': 2 * math.pi / d.omega[0],
                         'ku_T': d.ku[1], 'tu_T': 2 * math.pi / d.omega[1]}
    omegas = np.geomspace(mimo.ls_omega_max / 1000.0, mimo.ls_omega_max, 40).tolist()
    fit = mlt.mimo_pi_least_squares(
        lambda w: process(w) @ np.linalg.inv(decoupler(w)), omegas,
        (mimo.ls_omega0_h, mimo.ls_omega0_T), (mimo.ls_xi, mimo.ls_xi),
        (0.0, mimo.ls_dead_time_T), decoupler=decoupler)
    loops = (mlt.PiGains(float(fit.kp[0, 0]), float(fit.ki[0, 0])),
             mlt.PiGains(float(fit.kp[1, 1]), float(fit.ki[1, 1])))
    return loops, {'ls_residual': fit.residual}


class _Pi:
    """One loop's PI on the PI output v (the form of TwoLoopPi's loops), with back-calculation
    within ``[lo, hi]``; started bumplessly from ``v0`` at error ``e0``."""

    def __init__(self, gains: mlt.PiGains, h: float, lo: float, hi: float) -> None:
        self.kp, self.kih, self.lo, self.hi = gains.kp, gains.ki * h, lo, hi
        self.integral = 0.0

    def start(self, v0: float, e0: float) -> None:
        self.integral = v0 - self.kp * e0

    def step(self, e: float) -> float:
        w = self.kp * e + self.integral
        v = min(max(w, self.lo), self.hi)
        self.integral += self.kih * e + (v - w)
        return v


class MimoAutotuner(AutotuneMachine):
    """Controller (core/interfaces.py): :class:`TwoLoopPi` with [Precup2013] §3.7's auto-tuning (module
    docstring). ``start()``, ``abort()``, ``apply()``, ``revert()`` return ``(accepted,
    message)`` for std_srvs/Trigger services."""

    disturbance_names: tuple[str, ...] = ()
    TESTING = TESTING

    def __init__(self, config: TwoLoopPiConfig, mimo: MimoAutotuneConfig | None = None,
                 relay: AutotuneConfig | None = None, pi: TwoLoopPi | None = None) -> None:
        self.pi = pi if pi is not None else TwoLoopPi(config)
        self.output_names, self.input_names = self.pi.output_names, self.pi.input_names
        self.disturbance_names = self.pi.disturbance_names
        self.mimo = mimo or MimoAutotuneConfig(mode='relay')
        self.relay_cfg = relay or AutotuneConfig()
        check_config(self.mimo)
        check_config(self.relay_cfg)
        self._state, self._reason, self._state_time = 'idle', '', 0.0
        self._stepped_state = 'idle'
        self._scheduled_done = self._apply_done = False
        self._saved: TwoLoopPiConfig | None = None
        self._proposal: tuple[mlt.PiGains, mlt.PiGains] | None = None
        self._found: dict[str, float] = {}
        self._last_u: np.ndarray | None = None
        self._cycles = 0
        self._clear()

    # ------------------------------------------------------------------ API
    @property
    def sample_time(self) -> float:
        return self.pi.sample_time

    @property
    def config(self) -> TwoLoopPiConfig:
        return self.pi.config

    @property
    def proposal(self) -> tuple[mlt.PiGains, mlt.PiGains] | None:
        return self._proposal

    # operator requests: AutotuneMachine; its hooks
    def _start_refusal(self) -> str:
        if self.mimo.mode == 'none':
            return 'autotune.mode is none; set relay, model_zn or model_ls'
        if self.pi.scheduler is not None:
            return 'two_loop.schedule is active (the gains come from its table); tune without it'
        return ''

    def _begin(self) -> tuple[bool, str]:
        """relay: settle, then the sequential relay test; model_*: design at once."""
        self._saved = self.pi.config
        self._clear()
        self._found = {}
        if self.mimo.mode != 'relay':
            try:
                loops, self._found = model_design(self.pi.config, self.mimo)
                self._propose(loops)
            except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
                self._state, self._reason = 'failed', f'design failed: {exc}'
                return False, f'autotune: {self._reason}'
            return True, f'autotune: {self.mimo.mode} designed ({self._state})'
        self._state, self._reason = 'settling', ''
        return True, 'autotune: test started (settling)'

    def interrupted(self, reason: str) -> None:
        """Report a test that ended outside this tuner (state ``aborted`` with ``reason``): a
        live change of a setting rebuilt the controller, which runs the new settings' gains."""
        self._state, self._reason = 'aborted', reason

    def _has_proposal(self) -> bool:
        return self._proposal is not None

    def _apply_proposal(self) -> str:
        assert self._proposal is not None
        self._set_gains(self._with(self._proposal))
        self._state, self._reason = 'running', ''
        return 'applied ' + _gains_text(self._proposal)

    def _has_saved(self) -> bool:
        return self._saved is not None

    def _restore_saved(self) -> None:
        assert self._saved is not None
        self._set_gains(self._saved)

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        """Bumpless (re)start of the PI from ``u``; a running test is aborted (not one started
        before its first sample)."""
        if self._state in TESTING and self._stepped_state in TESTING:
            self._end('aborted', 'reset during the test')
        self.pi.reset(y, u)
        self._last_u = np.asarray(u, dtype=float).reshape(-1).copy()

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        t = float(t)
        cfg = self.relay_cfg
        if cfg.start_time > 0 and not self._scheduled_done and t >= cfg.start_time - 1e-9:
            self._scheduled_done = True
            self.start()
        if cfg.apply_time > 0 and not self._apply_done and t >= cfg.apply_time - 1e-9:
            self._apply_done = True
            if self._state == 'proposed':
                self.apply()
        if self._state == 'tuned':
            self._state = 'running'
        u = self._test_step(t, y, r, d) if self._state in TESTING else None
        if u is None:
            u = self.pi.step(t, y, r, d)
        self._last_u = np.array(u, dtype=float)
        if self._state != self._stepped_state:
            self._stepped_state, self._state_time = self._state, max(t, 0.0)
        return u

    @property
    def status(self) -> Mapping[str, Any]:
        st = dict(self.pi.status)
        st.update({'state': self._state, 'reason': self._reason, 'state_time': self._state_time,
                   'cycles': self._cycles, 'relay_stage': self._stage + 1 if self._relay
                   else 0})
        return st

    def results(self) -> dict[str, Any]:
        """Parameter values: ``autotune.*`` results and the running ``two_loop.*`` gains."""
        p, cfg = self._proposal, self.pi.config
        f = self._found
        return {
            'autotune.start': False, 'autotune.state': self._state,
            'autotune.reason': self._reason, 'autotune.state_time': float(self._state_time),
            'autotune.cycles': int(self._cycles),
            'autotune.relay_loop': LOOPS[STAGES[self._stage][0]] if self._relay else 'none',
            'autotune.relay_stage': self._stage + 1 if self._relay else 0,
            **{f'autotune.{k}': float(f.get(k, 0.0)) for k in (
                'ku_h', 'tu_h', 'ku_T', 'tu_T', 'ku_h_open', 'tu_h_open', 'ls_residual')},
            'autotune.proposed_kp_h': p[0].kp if p else 0.0,
            'autotune.proposed_ki_h': p[0].ki if p else 0.0,
            'autotune.proposed_kp_T': p[1].kp if p else 0.0,
            'autotune.proposed_ki_T': p[1].ki if p else 0.0,
            'two_loop.kp_h': cfg.kp_h, 'two_loop.ki_h': cfg.ki_h,
            'two_loop.kp_T': cfg.kp_T, 'two_loop.ki_T': cfg.ki_T,
        }

    # ------------------------------------------------------------ internals
    def _clear(self) -> None:
        self._t_start = math.nan
        self._r_test: tuple[float, float] | None = None
        self._win: deque[tuple[float, float, float, float, float]] = deque()  # t, y_h, y_T, v_h, v_T
        self._stage = 0
        self._relay: RelayAutotuner | None = None
        self._closed: _Pi | None = None
        self._v = [0.0, 0.0]            # PI outputs [v_h, v_T]
        self._loops: list[mlt.PiGains | None] = [None, None]
        self._d21 = D21Filter()
        self._cycles = 0

    def _with(self, loops: tuple[mlt.PiGains, mlt.PiGains]) -> TwoLoopPiConfig:
        return replace(self.pi.config, kp_h=loops[0].kp, ki_h=loops[0].ki, kp_T=loops[1].kp,
                       ki_T=loops[1].ki)

    def _set_gains(self, cfg: TwoLoopPiConfig) -> None:
        """The PI with ``cfg``, continuing bumplessly from the last output."""
        u = self._last_u
        self.pi = _renamed(TwoLoopPi(cfg), self.pi)
        if u is not None and np.all(np.isfinite(u)):
            self.pi.reset(np.full(2, math.nan), u)

    def _propose(self, loops: tuple[mlt.PiGains, mlt.PiGains]) -> None:
        cfg = self._with(loops)
        reason = cfg.reason()
        if reason:
            raise ValueError(f'the design is not a valid two-loop PI: {reason}')
        self._proposal = loops
        if self.relay_cfg.apply == 'auto':
            self._set_gains(cfg)
            self._state = 'tuned'
        else:
            self._state = 'proposed'
        self._reason = ''

    def _end(self, state: str, reason: str) -> None:
        """Leave the test: the gains from before it, bumplessly from the test's resting flows."""
        if self._relay is not None and self._relay.state in TESTING:
            self._relay.abort(reason)
        u_rest = self._resting_u()
        self.pi = _renamed(TwoLoopPi(self._saved or self.pi.config), self.pi)
        if u_rest is not None:
            self.pi.reset(np.full(2, math.nan), u_rest)
        self._relay, self._closed = None, None
        self._state, self._reason = state, reason

    def _resting_u(self) -> np.ndarray | None:
        """The flows of the PI outputs at rest (the relay's bias instead of its swing)."""
        if self._relay is None:
            return self._last_u
        v = list(self._v)
        i = STAGES[self._stage][0]
        u0 = self._relay.status['u0']
        if math.isfinite(u0):
            v[i] = float(u0)
        return self._flows(v, static=True)

    def _v_range(self) -> tuple[float, float]:
        cfg = self.pi.config
        if cfg.decoupling == 'none':
            return cfg.u_min, cfg.u_max
        lim = cfg.u_max if cfg.v_limit is None else cfg.v_limit
        return -lim, lim

    def _flows(self, v: list[float], static: bool = False) -> np.ndarray:
        """``u = D·v`` within the flow limits (the dynamic D21 stepped once unless ``static``)."""
        cfg = self.pi.config
        lo, hi = self._v_range()
        if cfg.decoupling == 'none':
            u = [v[0], v[1]]
        else:
            if cfg.decoupling == 'dynamic':
                c21 = _d21_gain(cfg) * v[0] if static else self._d21.step(v[0])
            else:
                c21 = cfg.d21 * v[0]
            u = [v[0] + min(max(cfg.d12 * v[1], lo), hi), v[1] + min(max(c21, lo), hi)]
        return np.clip(np.array(u), cfg.u_min, cfg.u_max)

    def _test_step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray
                   ) -> np.ndarray | None:
        yv = np.asarray(y, dtype=float).reshape(-1)
        rv = np.asarray(r, dtype=float).reshape(-1)
        if yv.size != 2 or rv.size != 2 or not (np.all(np.isfinite(yv))
                                                 and np.all(np.isfinite(rv))):
            self._end('failed', 'non-finite measurement or setpoint during the test')
            return None
        if self._r_test is None:
            self._t_start, self._r_test = t, (float(rv[0]), float(rv[1]))
        if (float(rv[0]), float(rv[1])) != self._r_test:
            self._end('failed', 'setpoint changed during the test')
            return None
        if self._state == 'settling':
            return self._settle(t, y, r, d, yv, rv)
        return self._relay_step(t, yv, rv)

    def _settle(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray, yv: np.ndarray,
                rv: np.ndarray) -> np.ndarray | None:
        """The PI runs until both outputs stay within settle_band of their (guarded) setpoints
        for settle_time (or settle_timeout passes); its outputs v are the relays' bias."""
        cfg = self.relay_cfg
        u = self.pi.step(t, y, r, d)
        st = self.pi.status
        self._win.append((t, float(yv[0]), float(yv[1]), st['v.h'], st['v.T_out']))
        while self._win and self._win[0][0] < t - cfg.settle_time - 1e-9:
            self._win.popleft()
        self._r_used = (st['r.h'], st['r.T_out'])
        calm = (t - self._t_start >= cfg.settle_time - 1e-9
                and all(abs(w[1] - self._r_used[0]) <= cfg.settle_band
                        and abs(w[2] - self._r_used[1]) <= cfg.settle_band for w in self._win))
        if not (calm or t - self._t_start >= cfg.settle_timeout):
            return u
        self._v = [float(np.mean([w[3] for w in self._win])),
                   float(np.mean([w[4] for w in self._win]))]
        self._d21.settle(self._v[0])
        self._begin_stage(0, yv)
        return self._relay_step(t, yv, rv)

    def _begin_stage(self, stage: int, yv: np.ndarray) -> None:
        """A relay on this stage's loop from its PI output; the other loop held (stage 0) or
        closed by its placed PI, started bumplessly from its output."""
        self._stage = stage
        i = STAGES[stage][0]
        cfg, mimo = self.pi.config, self.mimo
        lo, hi = self._v_range()
        running = (cfg.h_loop, cfg.t_loop)[i]
        sign = -1.0 if running.kp < 0 or (running.kp == 0 and running.ki < 0) else 1.0
        amplitude = mimo.relay_amplitude_h if i == 0 else mimo.relay_amplitude_T
        hysteresis = mimo.hysteresis_h if i == 0 else mimo.hysteresis_T
        relay_cfg = replace(self.relay_cfg, test='relay', relay_bias=0.0, additional_relay=0.0,
                            relay_amplitude=amplitude, hysteresis=hysteresis, noise_band=0.0,
                            bias_correction=True, rule='zn', kind='pi', model='auto',
                            process_gain=0.0, apply='auto', apply_time=0.0, start_time=0.0,
                            settle_time=0.0, settle_timeout=0.0, verify_step=0.0)
        pid = PidConfig(kp=sign, ti=math.inf, sample_time=cfg.sample_time, u_min=lo, u_max=hi)
        self._relay = RelayAutotuner(pid, relay_cfg, LOOPS[i], 'v')
        self._relay.reset(np.array([yv[i]]), np.array([self._v[i]]))
        self._relay.start()
        j = 1 - i
        other = self._loops[j]
        if other is None:
            self._closed = None
        else:
            self._closed = _Pi(other, cfg.sample_time, lo, hi)
            self._closed.start(self._v[j], self._r_used[j] - float(yv[j]))
        self._state = 'relay'

    def _relay_step(self, t: float, yv: np.ndarray, rv: np.ndarray) -> np.ndarray | None:
        i = STAGES[self._stage][0]
        j = 1 - i
        relay = self._relay
        assert relay is not None                   # set by _begin_stage
        r_i = np.array([self._r_used[i]])
        self._v[i] = float(relay.step(t, np.array([yv[i]]), r_i, np.zeros(0))[0])
        if self._closed is not None:
            self._v[j] = self._closed.step(self._r_used[j] - float(yv[j]))
        self._cycles = int(relay.status['cycles'])
        if relay.state in TESTING:
            self._state = 'measuring' if relay.state == 'measuring' else 'relay'
            return self._flows(self._v)
        if relay.state in ('failed', 'aborted'):
            self._end('failed', f'relay on loop {LOOPS[i]} (stage {self._stage + 1}): '
                                f'{relay.status["reason"]}')
            return None
        res = relay.result
        if res is None:
            self._end('failed', f'relay on loop {LOOPS[i]}: no ultimate point')
            return None
        # the relay's bias is v_i at rest; this stage's loop is placed at its ultimate point
        self._v[i] = float(relay.status['u0'])
        sign = 1.0 if relay.pid.config.kp > 0 else -1.0
        name = LOOPS[i].split('_')[0]
        self._found[f'ku_{name}'], self._found[f'tu_{name}'] = res.ku, res.tu
        if self._stage == 0:
            self._found['ku_h_open'], self._found['tu_h_open'] = res.ku, res.tu
        r_b, phi_b = self.mimo.loop_point
        try:
            self._loops[i] = mlt.place_point(sign / res.ku, 0.0, r_b, phi_b,
                                             2.0 * math.pi / res.tu)
        except ValueError as exc:
            self._end('failed', f'loop {LOOPS[i]}: {exc}')
            return None
        if self._stage + 1 < len(STAGES):
            self._begin_stage(self._stage + 1, yv)
            return self._relay_step(t, yv, rv)
        try:
            first, second = self._loops
            assert first is not None and second is not None   # both stages identified
            loops = (first, second)
            self._relay = None
            self._propose(loops)
        except ValueError as exc:
            self._end('failed', str(exc))
            return None
        u = self._flows(self._v, static=True)
        self.pi.reset(np.full(2, math.nan), u)
        self._closed = None
        return None


def _renamed(new: TwoLoopPi, old: TwoLoopPi) -> TwoLoopPi:
    """``new`` with the channels and the optional parts (scheduler, feedforward) of ``old``."""
    new.output_names, new.input_names = old.output_names, old.input_names
    new.disturbance_names = old.disturbance_names
    new.scheduler, new.feedforward = old.scheduler, old.feedforward
    return new


def _gains_text(loops: tuple[mlt.PiGains, mlt.PiGains]) -> str:
    return (f'kp_h {loops[0].kp:.4g}, ki_h {loops[0].ki:.4g}, kp_T {loops[1].kp:.4g}, '
            f'ki_T {loops[1].ki:.4g}')
