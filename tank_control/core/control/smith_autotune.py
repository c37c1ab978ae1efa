"""The auto-tuned Smith predictor: [Precup2013] §3.6's identification chain run on the live loop.

``idle → settling → relay → measuring → waiting → process_gain → tuned → running`` (Hang 1995,
[Precup2013] §3.6.1; [Precup2013] §3.6): while the Smith predictor holds the loop steady, a relay
test (:class:`~tank_control.core.control.relay_autotune.RelayAutotuner`, its relay replacing
the predictor and its primary) gives ku, Tu; a Ziegler–Nichols PI ([Precup2013] Table 3.1: kR = 0.45·ku,
Ti = 0.8·Tu) then runs the loop without predictor; at the next setpoint change, once the
transient has died out, ``kP = Δy∞/Δu∞``; eq. 3.6.2 gives T, Tm of ``kP·e^(−s·Tm)/(1 + sT)ⁿ``
(eq. 3.6.1, n = 1 or 2) and eq. 3.6.7 (n = 1, te) or 3.6.9 (n = 2, xi) the PI primary; the
Smith predictor on that model takes over bumplessly. ``failed`` / ``aborted`` put the Smith
predictor from before the test back, bumplessly. Times in s. docs/controllers.md ("smith_pi").
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tank_control.core.analysis.robustness import smith_report
from tank_control.core.control.autotune_machine import AutotuneMachine
from tank_control.core.control.pid import PidConfig
from tank_control.core.control.relay_autotune import AutotuneConfig, RelayAutotuner
from tank_control.core.control.smith import SmithModel, SmithPredictor
from tank_control.core.params import check_config
from tank_control.core.tuning import identification as ident
from tank_control.core.tuning.model import ProcessModel
from tank_control.core.tuning.rules import tune

STATES = ('idle', 'settling', 'relay', 'measuring', 'waiting', 'process_gain', 'tuned',
          'running', 'failed', 'aborted')
TESTING = ('settling', 'relay', 'measuring', 'waiting', 'process_gain')
STEADY_U = 0.005
"""``process_gain``: the mean input of the last window may differ from the window before by at
most this fraction of its change since the setpoint step (as the step test's output)."""
ZN_RULE = 'zn_004_q0'
"""[Precup2013] Table 3.1's Ziegler–Nichols PI: kR = 0.45·ku, Ti = 0.8·Tu."""


@dataclass(frozen=True)
class SmithDesign:
    """The design of the primary: model order n (1 or 2), te [s] for n = 1 ([Precup2013] eq. 3.6.7),
    xi for n = 2 (eq. 3.6.9) — the ``tuning.order``, ``tuning.te``, ``tuning.xi`` parameters."""

    order: int = 1
    te: float = 0.0
    xi: float = 0.0

    def reason(self) -> str | None:
        if self.order not in (1, 2):
            return f'tuning.order: {self.order} is not 1 or 2'
        if self.order == 1 and not self.te > 0:
            return ('tuning.te: the auto-tuned Smith predictor with tuning.order 1 needs the '
                    'closed-loop time constant te > 0 ([Precup2013] eq. 3.6.7: te = (0.2…1)·T)')
        if self.order == 2 and not 0 < self.xi <= 1:
            return ('tuning.xi: the auto-tuned Smith predictor with tuning.order 2 needs the '
                    'damping xi in (0, 1] ([Precup2013] eq. 3.6.9: xi in [0.5, 1])')
        return None


def process_gain(y_before: float, y_after: float, u_before: float, u_after: float) -> float:
    """``kP = Δy∞/Δu∞``: the steady output change over the steady input change of a
    closed-loop setpoint step ([Precup2013] §3.6, step 3; the document gives no formula)."""
    du = u_after - u_before
    if du == 0.0 or not math.isfinite(du):
        raise ValueError('the steady input did not change with the setpoint: no process gain')
    return (y_after - y_before) / du


def smith_model(ku: float, tu: float, gain: float, order: int) -> SmithModel:
    """The internal model ``kP·e^(−s·Tm)/(1 + sT)ⁿ`` ([Precup2013] eq. 3.6.1) through the ultimate
    point and the static gain (eq. 3.6.2): ``fopdt`` (n = 1) or ``sopdt`` with T2 = T (n = 2)."""
    fit = ident.fopdt_from_ultimate(ku, tu, gain, order)
    if fit.time_constant <= 0.0:
        raise ValueError(f'eq. 3.6.2 gives T = {fit.time_constant:g} s: kP·ku = '
                         f'{gain * ku:.4g} is too close to 1 for a lag')
    return SmithModel('fopdt' if order == 1 else 'sopdt', gain, fit.time_constant,
                      fit.dead_time, time_constant2=fit.time_constant)


def smith_primary(model: SmithModel, design: SmithDesign, running: PidConfig) -> PidConfig:
    """The PI primary of [Precup2013] eq. 3.6.7 (n = 1) or 3.6.9 (n = 2) on ``model``, with the running
    primary's sample time, limits and setpoint weight."""
    args = {'te': design.te} if design.order == 1 else {'xi': design.xi}
    g = tune('smith_pi', 'pi', gain=model.gain, time_constant=model.time_constant,
             n=design.order, **args)
    return replace(running, kp=float(g['kp']), ti=float(g['ti']))


def model_of(model: SmithModel) -> ProcessModel:
    """The Smith model as a :class:`ProcessModel` (the gain's magnitude)."""
    if model.model == 'sopdt':
        t1, t2 = model.time_constant, model.time_constant2
        return ProcessModel('sopdt', abs(model.gain), model.dead_time, max(t1, t2), min(t1, t2))
    return ProcessModel(model.model, abs(model.gain), model.dead_time,
                        model.time_constant if model.model == 'fopdt' else 0.0)


class SmithAutotuner(AutotuneMachine):
    """SISO Controller (core/interfaces.py): a :class:`SmithPredictor` with [Precup2013] §3.6's
    auto-tuning chain (see the module docstring). Idle, it is the Smith predictor exactly.

    ``autotune``: the relay and settling settings (``autotune.*``); ``design``: the primary's
    design. ``start()``/``abort()`` return ``(accepted, message)`` (std_srvs/Trigger).
    """

    disturbance_names: tuple[str, ...] = ()
    TESTING = TESTING
    COMMANDS = ('start_autotune', 'abort_autotune')
    RESTORED = 'the Smith predictor from before restored'

    def __init__(self, model: SmithModel, primary: PidConfig,
                 autotune: AutotuneConfig | None = None, design: SmithDesign | None = None,
                 output_name: str = 'y', input_name: str = 'u') -> None:
        self.smith = SmithPredictor(model, primary, output_name, input_name)
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self._cfg = autotune or AutotuneConfig()
        check_config(self._cfg)
        self.design = design or SmithDesign()
        self.ms_max = 0.0
        """Bound on Ms of the designed Smith loop on its model (``robustness.ms_max``; 0 = none)."""
        self._state, self._reason, self._state_time = 'idle', '', 0.0
        self._stepped_state = 'idle'
        self._scheduled_done = False
        self._relay: RelayAutotuner | None = None
        self._last_out: float | None = None
        self._ku = self._tu = self._ku_df = self._tu_df = 0.0
        self._kp_measured = math.nan
        self._cycles = 0
        self._tuned = False              # the running model came from a chain
        self._clear()

    # ------------------------------------------------------------------ API
    @property
    def model(self) -> SmithModel:
        """The running Smith predictor's internal model."""
        return self.smith.model

    @property
    def primary(self) -> Any:
        """The running Smith predictor's PI primary (a ``Pid2Dof``)."""
        return self.smith.primary

    @property
    def sample_time(self) -> float:
        return self.smith.sample_time

    @property
    def config(self) -> AutotuneConfig:
        return self._cfg

    @property
    def relay(self) -> RelayAutotuner | None:
        """The relay test and its ZN PI while the chain runs (None otherwise)."""
        return self._relay

    def configure(self, autotune: AutotuneConfig) -> None:
        """Replace the ``autotune.*`` settings (not while a test runs: ValueError)."""
        if self._state in TESTING:
            raise ValueError('autotune: settings cannot change while a test is running; abort '
                             'it first')
        check_config(autotune)
        if autotune.start_time != self._cfg.start_time:
            self._scheduled_done = False
        self._cfg = autotune

    # operator requests (start, abort, command): AutotuneMachine; its hooks
    def _start_refusal(self) -> str:
        return self.design.reason() or ''

    def _begin(self) -> tuple[bool, str]:
        """The chain, settling under the Smith predictor first."""
        self._clear()
        self._state, self._reason = 'settling', ''
        return True, 'autotune: test started (settling)'

    def set_manual(self, u: float | None = None) -> None:
        self.smith.set_manual(u)

    def set_auto(self) -> None:
        self.smith.set_auto()

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        """Bumpless (re)start of the Smith predictor from ``u``; a running chain is aborted
        (not one started before its first sample: a warm start only sets the output)."""
        if self._state in TESTING and self._stepped_state in TESTING:
            self._end('aborted', 'reset during the test')
        self.smith.reset(y, u)
        self._last_out = float(np.asarray(u, dtype=float).reshape(-1)[0])

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        t = float(t)
        if (self._cfg.start_time > 0 and not self._scheduled_done
                and t >= self._cfg.start_time - 1e-9):
            self._scheduled_done = True
            self.start()
        if self._state == 'tuned':
            self._state = 'running'
        u = self._test_step(t, y, r, d) if self._state in TESTING else None
        if u is None:
            u = float(self.smith.step(t, y, r, d)[0])
        self._last_out = u
        if self._state != self._stepped_state:
            self._stepped_state, self._state_time = self._state, max(t, 0.0)
        return np.array([u])

    @property
    def status(self) -> Mapping[str, Any]:
        st = dict(self.smith.status)
        st.update({'state': self._state, 'reason': self._reason, 'state_time': self._state_time,
                   'cycles': self._cycles, 'ku': self._ku or math.nan,
                   'tu': self._tu or math.nan, 'process_gain': self._kp_measured})
        if self._relay is not None:
            st['relay'] = dict(self._relay.status)
        return st

    def results(self) -> dict[str, Any]:
        """Parameter values: ``autotune.*`` results, and the running ``smith.*`` model and
        primary ``kp``, ``ti`` (what the chain designed, once tuned)."""
        m, p = self.smith.model, self.smith.primary.config
        tuned = self._tuned
        return {
            'autotune.start': False, 'autotune.state': self._state,
            'autotune.reason': self._reason, 'autotune.state_time': float(self._state_time),
            'autotune.cycles': int(self._cycles), 'autotune.ku': float(self._ku),
            'autotune.tu': float(self._tu), 'autotune.ku_df': float(self._ku_df),
            'autotune.tu_df': float(self._tu_df),
            'autotune.model_kind': m.model if tuned else 'none',
            'autotune.model_method': 'eq_3_6_2' if tuned else 'none',
            'autotune.model_gain': float(m.gain) if tuned else 0.0,
            'autotune.model_time_constant': float(m.time_constant) if tuned else 0.0,
            'autotune.model_time_constant2': float(m.time_constant2)
            if tuned and m.model == 'sopdt' else 0.0,
            'autotune.model_dead_time': float(m.dead_time) if tuned else 0.0,
            'smith.model': m.model, 'smith.gain': float(m.gain),
            'smith.time_constant': float(m.time_constant),
            'smith.time_constant2': float(m.time_constant2), 'smith.dead_time': float(m.dead_time),
            'kp': float(p.kp), 'ti': float(p.ti) if math.isfinite(p.ti) else 0.0,
        }

    # ------------------------------------------------------------ internals
    def _clear(self) -> None:
        self._relay = None
        self._t_start = math.nan
        self._r_test = math.nan
        self._win: deque[tuple[float, float, float]] = deque()     # (t, y, u)
        self._before: tuple[float, float, float] | None = None    # (r, ȳ, ū) before the step
        self._rec: list[tuple[float, float, float]] = []           # (t, y, u) since the step
        self._t_step = math.nan
        self._cycles = 0
        self._u0 = math.nan

    def _end(self, state: str, reason: str) -> None:
        """Leave the chain: the Smith predictor from before, restarted from the relay's bias
        u0 (the equilibrium input) during the relay, else from the last output."""
        if self._relay is not None and self._relay.state in ('settling', 'relay', 'measuring'):
            self._relay.abort(reason)
        u = self._u0 if self._state in ('relay', 'measuring') and math.isfinite(self._u0) \
            else self._last_out
        if u is not None and math.isfinite(u):
            self.smith.reset(np.array([math.nan]), np.array([u]))
        self._relay = None
        self._state, self._reason = state, reason

    def _window(self, t: float, y: float, u: float) -> None:
        self._win.append((t, y, u))
        while self._win and self._win[0][0] < t - self._cfg.settle_time - 1e-9:
            self._win.popleft()

    def _calm(self, t: float, r: float, since: float) -> bool:
        """Within ``settle_band`` of ``r`` for ``settle_time`` (the window full since ``since``)."""
        cfg = self._cfg
        return (t - since >= cfg.settle_time - 1e-9
                and all(abs(y - r) <= cfg.settle_band for _, y, _ in self._win))

    def _test_step(self, t: float, y_in: np.ndarray, r_in: np.ndarray, d: np.ndarray
                   ) -> float | None:
        y = float(np.asarray(y_in, dtype=float).reshape(-1)[0])
        r = float(np.asarray(r_in, dtype=float).reshape(-1)[0])
        if not (math.isfinite(y) and math.isfinite(r)):
            self._end('failed', 'non-finite measurement or setpoint during the test')
            return None
        if math.isnan(self._t_start):
            self._t_start, self._r_test = t, r
        if self._state == 'settling':
            return self._settle(t, y, r, y_in, r_in, d)
        if self._state in ('relay', 'measuring'):
            return self._relay_step(t, y_in, r_in, d)
        return self._zn_step(t, y, r, y_in, r_in, d)

    def _settle(self, t: float, y: float, r: float, y_in: np.ndarray, r_in: np.ndarray,
                d: np.ndarray) -> float | None:
        """The Smith predictor runs until the output stays within settle_band for settle_time
        (or settle_timeout passes); then the relay test starts from the mean input u0 with the
        hysteresis max(autotune.hysteresis, noise_band·σ) (σ of the settled output)."""
        cfg = self._cfg
        if r != self._r_test:
            self._end('failed', 'setpoint changed during the test')
            return None
        u = float(self.smith.step(t, y_in, r_in, d)[0])
        self._window(t, y, u)
        if not (self._calm(t, r, self._t_start) or t - self._t_start >= cfg.settle_timeout):
            return u
        ys = np.array([w[1] for w in self._win])
        sigma = float(np.std(np.diff(ys)) / math.sqrt(2.0)) if len(ys) > 2 else 0.0
        self._u0 = float(np.mean([w[2] for w in self._win]))
        relay_cfg = replace(cfg, test='relay', relay_bias=0.0, rule=ZN_RULE, kind='pi',
                            model='auto', process_gain=0.0, apply='auto', apply_time=0.0,
                            start_time=0.0, settle_time=0.0, settle_timeout=0.0,
                            hysteresis=max(cfg.hysteresis, cfg.noise_band * sigma),
                            noise_band=0.0, verify_step=0.0)
        primary = self.smith.primary.config
        self._relay = RelayAutotuner(replace(primary, td=0.0, c=0.0), relay_cfg,
                                     self.output_names[0], self.input_names[0])
        self._relay.reset(y_in, np.array([self._u0]))
        self._relay.start()
        self._state = 'relay'
        return self._relay_step(t, y_in, r_in, d)

    def _relay_step(self, t: float, y_in: np.ndarray, r_in: np.ndarray, d: np.ndarray
                    ) -> float | None:
        relay = self._relay
        assert relay is not None                   # set while the chain is in a relay state
        u = float(relay.step(t, y_in, r_in, d)[0])
        self._cycles = relay.status['cycles']
        if relay.state in ('relay', 'measuring', 'settling'):
            self._state = 'measuring' if relay.state == 'measuring' else 'relay'
            return u
        if relay.state in ('failed', 'aborted'):
            self._end('failed', f'relay test: {relay.status["reason"]}')
            return None
        res = relay.result
        if relay.state not in ('tuned', 'running') or res is None:
            warning = relay.results()['autotune.warning']
            self._end('failed', f'relay test: the ZN PI was not applied ({warning or relay.state})')
            return None
        self._ku, self._tu, self._ku_df, self._tu_df = res.ku, res.tu, res.ku_df, res.tu_df
        self._state = 'waiting'
        self._win.clear()
        self._t_start, self._r_test = t, float(np.asarray(r_in, dtype=float).reshape(-1)[0])
        return u

    def _zn_step(self, t: float, y: float, r: float, y_in: np.ndarray, r_in: np.ndarray,
                 d: np.ndarray) -> float | None:
        """The ZN PI runs the loop. ``waiting``: a setpoint change that finds the loop calm
        (within settle_band for settle_time) and larger than 2·settle_band starts
        ``process_gain``. There, steady = within settle_band for settle_time and the mean input
        of that window within :data:`STEADY_U` of its change from the window before; then
        kP, the model and the primary, and the Smith predictor takes over."""
        cfg = self._cfg
        if r != self._r_test:
            calm = self._state == 'waiting' and self._calm(t, self._r_test, self._t_start)
            if calm and abs(r - self._r_test) > 2.0 * cfg.settle_band:
                self._before = (self._r_test, float(np.mean([w[1] for w in self._win])),
                                float(np.mean([w[2] for w in self._win])))
                self._state, self._t_step, self._rec = 'process_gain', t, []
            else:       # not a usable step: wait for the next calm change
                self._state = 'waiting'
            self._win.clear()
            self._t_start, self._r_test = t, r
        assert self._relay is not None             # it holds the output during the step test
        u = float(self._relay.step(t, y_in, r_in, d)[0])
        self._window(t, y, u)
        if self._state == 'waiting':
            return u
        self._rec.append((t, y, u))
        if t - self._t_step > cfg.timeout:
            self._end('failed', f'no steady response to the setpoint step within '
                                f'autotune.timeout = {cfg.timeout:g} s')
            return None
        if not self._calm(t, r, self._t_step + cfg.settle_time):
            return u
        n = len(self._win)
        prev = [w[2] for w in self._rec[-2 * n:-n]]
        u_last = float(np.mean([w[2] for w in self._win]))
        u_prev = float(np.mean(prev)) if prev else math.nan
        assert self._before is not None            # set when the step began
        r0, y0, u0 = self._before
        if not abs(u_last - u_prev) <= STEADY_U * abs(u_last - u0):
            return u
        return self._identify(t, u, y0, float(np.mean([w[1] for w in self._win])), u0, u_last,
                              y_in, r_in, d)

    def _identify(self, t: float, u: float, y0: float, y1: float, u0: float, u1: float,
                  y_in: np.ndarray, r_in: np.ndarray, d: np.ndarray) -> float | None:
        ku, tu = ((self._ku, self._tu) if self._cfg.method == 'first_harmonic'
                  else (self._ku_df, self._tu_df))
        try:
            kp = process_gain(y0, y1, u0, u1)
            self._kp_measured = kp
            if kp <= 0.0:
                raise ValueError(f'kP = {kp:.4g} is not positive; the Smith predictor with its '
                                 'PI primary (kp > 0) needs a positive process gain')
            model = smith_model(ku, tu, kp, self.design.order)
            primary = smith_primary(model, self.design, self.smith.primary.config)
            report = smith_report(model_of(model), primary)
            if not report.stable:
                raise ValueError(f'the designed Smith PI (kp {primary.kp:.4g}, ti '
                                 f'{primary.ti:.4g} s) is unstable on its model')
            if self.ms_max > 0 and report.ms > self.ms_max:
                raise ValueError(f'Ms would be {report.ms:.3g} > robustness.ms_max '
                                 f'{self.ms_max:g} on the model {report.model}')
            new = SmithPredictor(model, primary, self.output_names[0], self.input_names[0])
        except (ValueError, ArithmeticError) as exc:
            self._end('failed', f'identification/design failed: {exc}')
            return None
        # the loop is steady: the new internal model starts at rest at the last output
        new.reset(y_in, np.array([u]))
        new.step(t, y_in, r_in, d)       # completes the reset: returns u
        self.smith, self._relay, self._tuned = new, None, True
        self._state, self._reason = 'tuned', ''
        return u
