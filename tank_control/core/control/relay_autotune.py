"""Relay auto-tuner: a PID that identifies its process with a relay test and tunes itself.

001 §1.3 (Fig. 6.16, PID and on-off controller in parallel) and 004 §3.2–3.3, made safe to run
on a live loop: ``idle → settling → relay → measuring → tuned → running``, with ``failed`` /
``aborted`` restoring the previous gains bumplessly. The ultimate point comes from
:func:`~tank_control.core.tuning.identification.identify_relay`, the gains from
:func:`~tank_control.core.tuning.rules.tune`. Times in s, signals in the loop's units.
States, faults and starting: docs/controllers.md ("relay_autotune").
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tank_control.core.control.pid import PidConfig, Pid2Dof
from tank_control.core.params import check_config, param
from tank_control.core.tuning import identification as ident

STATES = ('idle', 'settling', 'relay', 'measuring', 'tuned', 'running', 'failed', 'aborted')
TESTING = ('settling', 'relay', 'measuring')
RULES_ULTIMATE = ('zn', 'zn_001', 'zn_004_q0', 'zn_004_q1')
RULES_IPDT = ('mdp', 'experimental')
RULES_FOPDT = ('oppelt', 'cohen_coon')
RULES = RULES_ULTIMATE + RULES_IPDT + RULES_FOPDT


_BIG = 1e12


def _at(default: Any, description: str, field_name: str, **meta: Any) -> Any:
    return param(default, description, name='autotune.' + field_name, **meta)


@dataclass(frozen=True)
class AutotuneConfig:
    """Settings of the relay test; each field is the parameter ``autotune.<field>``."""

    relay_amplitude: float = _at(1.0, 'relay amplitude d around the bias u0', 'relay_amplitude',
                                 unit='u units', min=1e-9, max=_BIG,
                                 source='001 eq. 6.22, 004 eq. 3.2.1')
    hysteresis: float = _at(0.0, 'relay hysteresis ε (noise band, 004 Fig. 3.3); the larger of '
                            'this and noise_band·σ is used', 'hysteresis', unit='y units',
                            min=0.0, max=_BIG)
    noise_band: float = _at(4.0, 'automatic hysteresis in units of the noise standard deviation '
                            'σ estimated while settling; 0 = off', 'noise_band', unit='-',
                            min=0.0, max=100.0)
    bias_correction: bool = _at(True, 'move the relay bias u0 to the mean input of a cycle whose '
                                'half-periods are asymmetric', 'bias_correction')
    asymmetry_tol: float = _at(0.1, '|Tu1 − Tu2|/period above which the bias is corrected',
                               'asymmetry_tol', unit='-', min=0.0, max=1.0)
    min_cycles: int = _at(4, 'stationary relay periods used for identification (004 §3.3: at '
                          'least four)', 'min_cycles', min=2, max=100)
    stationarity_tol: float = _at(0.05, 'relative spread of periods and first-harmonic '
                                  'amplitudes allowed among the measured cycles',
                                  'stationarity_tol', unit='-', min=1e-4, max=1.0)
    timeout: float = _at(600.0, 'longest relay + measuring time before the test fails',
                         'timeout', unit='s', min=1e-3, max=_BIG)
    settle_time: float = _at(10.0, 'the output must stay within settle_band of the setpoint this '
                             'long before the relay starts', 'settle_time', unit='s', min=0.0,
                             max=_BIG)
    settle_band: float = _at(1.0, 'steady band around the setpoint for settling', 'settle_band',
                             unit='y units', min=0.0, max=_BIG)
    settle_timeout: float = _at(300.0, 'after this long in settling the relay starts anyway',
                                'settle_timeout', unit='s', min=0.0, max=_BIG)
    max_amplitude: float = _at(0.0, 'largest |y − setpoint| allowed during the test; exceeding '
                               'it fails the test; 0 = no limit', 'max_amplitude',
                               unit='y units', min=0.0, max=_BIG)
    method: str = _at('first_harmonic', 'ultimate point used for tuning: first_harmonic (004 '
                      'eqs. 3.3.19–3.3.21, corrected to −180°) or describing_function (001 eq. '
                      '6.22)', 'method', choices=('first_harmonic', 'describing_function'))
    model: str = _at('auto', 'model identified from the relay data (004 §3.3, 3.6.2)', 'model',
                     choices=('auto', 'fopdt', 'ipdt'))
    process_gain: float = _at(0.0, 'known static gain kP for the FOPDT model (004 eq. 3.6.2); '
                              '0 = identify', 'process_gain', unit='y units per u unit',
                              min=0.0, max=_BIG)
    rule: str = _at('zn_001', 'tuning rule: zn / zn_001 / zn_004_q0 / zn_004_q1 from ku, tu; mdp / '
                    'experimental from the IPDT model; oppelt / cohen_coon from the FOPDT model',
                    'rule', choices=RULES)
    kind: str = _at('pid', 'controller type the rule designs', 'kind', choices=('p', 'pi', 'pid'))
    start_time: float = _at(0.0, "start a test at the first sample at or after this time (the "
                            "loop's simulated time), once; 0 = no scheduled start. Lets an "
                            'in-process run and a lockstep ROS run start at the same sample',
                            'start_time', unit='s', min=0.0, max=_BIG)


@dataclass(frozen=True)
class AutotuneCommand:
    """``autotune.start``: set true to start a test (the node sets it back to false)."""

    start: bool = _at(False, 'set true to start a relay test (the node resets it to false; same '
                      'as the ~/start_autotune service)', 'start')


@dataclass(frozen=True)
class AutotuneResults:
    """What the last test found (read-only parameters written from :meth:`RelayAutotuner.results`);
    0 / ``none`` before a successful test."""

    state: str = _at('idle', 'state of the auto-tuner', 'state', choices=STATES, read_only=True)
    reason: str = _at('', 'why the last test failed or was aborted', 'reason', read_only=True)
    state_time: float = _at(0.0, 'loop time of the first sample in the current state (simulated '
                            'time in sim/lockstep)', 'state_time', unit='s', min=0.0, max=_BIG,
                            read_only=True)
    cycles: int = _at(0, 'complete relay cycles counted since the relay started or the bias was '
                      'last corrected', 'cycles', min=0, max=1_000_000, read_only=True)
    ku: float = _at(0.0, 'identified ultimate gain Ku, first harmonic corrected to −180°', 'ku',
                    unit='u units per y unit', min=0.0, max=_BIG, read_only=True)
    tu: float = _at(0.0, 'identified ultimate period Tu', 'tu', unit='s', min=0.0, max=_BIG,
                    read_only=True)
    ku_df: float = _at(0.0, 'describing-function Ku = 4d/(πa) (001 eq. 6.22)', 'ku_df', min=0.0,
                       max=_BIG, read_only=True)
    tu_df: float = _at(0.0, 'mean relay period', 'tu_df', unit='s', min=0.0, max=_BIG,
                       read_only=True)
    model_kind: str = _at('none', 'identified model', 'model_kind', choices=('none', 'fopdt', 'ipdt'),
                          read_only=True)
    model_gain: float = _at(0.0, 'model gain K (FOPDT) or k1 (IPDT, per s)', 'model_gain',
                            min=-_BIG, max=_BIG, read_only=True)
    model_time_constant: float = _at(0.0, 'model time constant T', 'model_time_constant',
                                     unit='s', min=0.0, max=_BIG, read_only=True)
    model_dead_time: float = _at(0.0, 'model dead time L or To', 'model_dead_time', unit='s',
                                 min=0.0, max=_BIG, read_only=True)


class RelayAutotuner:
    """SISO Controller (core/interfaces.py): a :class:`Pid2Dof` with a relay auto-tuning test.

    ``pid_config``: the PID in normal operation (its limits bound the relay too);
    ``autotune``: the test settings. Channels: reads ``output_name``, writes ``input_name``.
    Designed to be driven by a node: ``start()``/``abort()`` return ``(accepted, message)``
    (a std_srvs/Trigger answer), ``state``/``status`` are plain values; ``status['state']``
    and, after ``failed``/``aborted``, ``status['reason']``.
    """

    disturbance_names: tuple[str, ...] = ()

    def __init__(self, pid_config: PidConfig, autotune: AutotuneConfig | None = None,
                 output_name: str = 'y', input_name: str = 'u') -> None:
        self.pid = Pid2Dof(pid_config)
        self.output_names = (output_name,)
        self.input_names = (input_name,)
        self._cfg = autotune or AutotuneConfig()
        self._check_config(self._cfg)
        self._state = 'idle'
        self._reason = ''
        self._state_time = 0.0                  # first sample in the current state [s]
        self._stepped_state = 'idle'            # state after the previous step
        self._pending: float | None = None      # bumpless PID (re)start from this u
        self._last_out: float | None = None     # last output sent [u units]
        self._saved_gains: dict[str, Any] | None = None
        self._result: ident.RelayIdentification | None = None
        self._gains: dict[str, float | None] | None = None
        self._cycles = 0
        self._scheduled_done = False            # autotune.start_time has fired
        self._clear_test()

    # ------------------------------------------------------------------ API
    @property
    def sample_time(self) -> float:
        return self.pid.config.sample_time

    @property
    def state(self) -> str:
        return self._state

    @property
    def config(self) -> AutotuneConfig:
        return self._cfg

    @property
    def result(self) -> ident.RelayIdentification | None:
        """The identification of the last successful test."""
        return self._result

    def configure(self, autotune: AutotuneConfig) -> None:
        """Replace the test settings (not while a test runs: ValueError)."""
        if self._state in TESTING:
            raise ValueError('autotune: settings cannot change while a test is running; abort it first')
        self._check_config(autotune)
        if autotune.start_time != self._cfg.start_time:
            self._scheduled_done = False          # a new scheduled start is armed
        self._cfg = autotune

    def start(self) -> tuple[bool, str]:
        """Begin a test (from idle, running, tuned, failed or aborted). Returns ``(accepted, message)``."""
        if self._state in TESTING:
            return False, f'autotune: a test is already running (state {self._state})'
        self._saved_gains = _gain_fields(self.pid.config)
        self._clear_test()
        self._state = 'settling'
        self._reason = ''
        return True, 'autotune: test started (settling)'

    def abort(self, reason: str = 'abort requested') -> tuple[bool, str]:
        """End a running test now: previous gains restored, the PID resumes from u0 at the next sample."""
        if self._state not in TESTING:
            return False, f'autotune: no test is running (state {self._state})'
        self._end('aborted', reason)
        return True, 'autotune: test aborted, previous gains restored'

    def command(self, name: str) -> tuple[bool, str]:
        """Operator commands for a node's std_srvs/Trigger services: ``start_autotune``, ``abort_autotune``."""
        if name == 'start_autotune':
            return self.start()
        if name == 'abort_autotune':
            return self.abort()
        raise ValueError(f'command: {name!r} is unknown; allowed start_autotune, abort_autotune')

    def results(self) -> dict[str, Any]:
        """Parameter values the tuner produced (see :class:`AutotuneResults`), the PID's
        gains in parameter convention (ti = 0: no integral action) and ``autotune.start`` = False
        (so a node re-arms its start parameter)."""
        res = self._result
        model = res.model if res else None
        cfg = self.pid.config
        return {
            'autotune.start': False,
            'autotune.state': self._state,
            'autotune.reason': self._reason,
            'autotune.state_time': float(self._state_time),
            'autotune.cycles': int(self._cycles),
            'autotune.ku': float(res.ku) if res else 0.0,
            'autotune.tu': float(res.tu) if res else 0.0,
            'autotune.ku_df': float(res.ku_df) if res else 0.0,
            'autotune.tu_df': float(res.tu_df) if res else 0.0,
            'autotune.model_kind': model.kind if model else 'none',
            'autotune.model_gain': float(model.gain) if model else 0.0,
            'autotune.model_time_constant': float(getattr(model, 'time_constant', 0.0)) if model else 0.0,
            'autotune.model_dead_time': float(model.dead_time) if model else 0.0,
            'kp': abs(cfg.kp), 'ti': cfg.ti if math.isfinite(cfg.ti) else 0.0, 'td': cfg.td,
            'b': cfg.b, 'c': cfg.c,
        }

    def reset(self, y: np.ndarray, u: np.ndarray) -> None:
        """Bumpless (re)start of normal PID operation from ``u``; a running test is abandoned
        (aborted). A test started before its first sample (``autotune.start`` at start-up) is
        kept: the warm start at the first sample (``core.loop.warm_start``) only sets the
        output the PID starts from."""
        u0 = _scalar(u, 'u')
        if not math.isfinite(u0):
            raise ValueError(f'reset: u = {u0!r} is not finite')
        if self._state in TESTING and self._stepped_state in TESTING:
            self._end('aborted', 'reset during the test')
        self._pending = u0
        self._last_out = u0

    def step(self, t: float, y: np.ndarray, r: np.ndarray, d: np.ndarray) -> np.ndarray:
        """One sample: time [s], measurement, setpoint → manipulated input (1 value).

        The PID's rate limit also holds across the hand-overs PID → relay → PID. At the
        first sample with ``t >= autotune.start_time`` (when > 0) a test starts, once
        (re-armed when start_time changes), exactly as :meth:`start` before that sample.
        """
        yv, rv = _scalar(y, 'y'), _scalar(r, 'r')
        if (self._cfg.start_time > 0 and not self._scheduled_done
                and float(t) >= self._cfg.start_time - 1e-9):
            self._scheduled_done = True
            self.start()          # refused (no effect) if a test is already running
        u = None
        if self._state in TESTING:
            u = self._test_step(float(t), yv, rv)
        elif self._state == 'tuned':
            self._state = 'running'
        if u is None:
            u = self._limit(self._pid_step(yv, rv))
        self._last_out = u
        if self._state != self._stepped_state:   # also a start()/abort() between samples
            self._stepped_state, self._state_time = self._state, max(float(t), 0.0)
        return np.array([u])

    @property
    def status(self) -> Mapping[str, Any]:
        """state, reason, state_time (loop time of the first sample in the state [s]), cycles
        (complete relay cycles counted), u0 (relay bias), hysteresis ε,
        noise_std σ, ku, tu (first harmonic, corrected), ku_df, tu_df (describing function),
        amplitude, model (dict), model_method, gains (dict from the rule) and the PID status
        under 'pid'. Results are those of the last successful test (NaN/empty before one)."""
        res = self._result
        status: dict[str, Any] = {
            'state': self._state,
            'reason': self._reason,
            'state_time': self._state_time,
            'cycles': self._cycles,
            'u0': self._u0 if self._u0 is not None else math.nan,
            'hysteresis': self._eps,
            'noise_std': self._sigma,
            'ku': res.ku if res else math.nan,
            'tu': res.tu if res else math.nan,
            'ku_df': res.ku_df if res else math.nan,
            'tu_df': res.tu_df if res else math.nan,
            'amplitude': res.amplitude if res else math.nan,
            'model': dict(res.model.as_dict()) if res else {},
            'model_method': res.model_method if res else '',
            'gains': dict(self._gains) if self._gains else {},
        }
        status['pid'] = dict(self.pid.status)
        return status

    # ------------------------------------------------------------ internals
    @staticmethod
    def _check_config(cfg: AutotuneConfig) -> None:
        check_config(cfg)

    def _clear_test(self) -> None:
        self._t_start = math.nan       # start of the current phase [s]
        self._r_test = math.nan
        self._win_t: deque[float] = deque()
        self._win_y: deque[float] = deque()
        self._win_u: deque[float] = deque()
        self._u0: float | None = None
        self._u0_start: float | None = None
        self._sigma = math.nan
        self._eps = math.nan
        self._relay_high = True
        self._rec_t: list[float] = []
        self._rec_u: list[float] = []
        self._rec_y: list[float] = []
        self._first_cycle = 0
        self._cycles = 0

    def _pid_step(self, y: float, r: float) -> float:
        if self._pending is not None:
            if not (math.isfinite(y) and math.isfinite(r)):
                return self._clip(self._pending)
            self.pid.reset(r, y, self._pending)
            self._pending = None
        return self.pid.update(r, y)

    def _clip(self, u: float) -> float:
        cfg = self.pid.config
        return min(max(u, cfg.u_min), cfg.u_max)

    def _amplitude(self) -> float:
        """``autotune.relay_amplitude``, reduced so that ``u0 ± d`` stays within the output limits
        (a clipped, asymmetric relay would defeat the bias correction)."""
        cfg = self.pid.config
        return min(self._cfg.relay_amplitude, cfg.u_max - self._u0, self._u0 - cfg.u_min)

    def _limit(self, u: float) -> float:
        """The PID's output limits and rate limit (du_max per second) applied to the relay output."""
        cfg = self.pid.config
        if self._last_out is not None and math.isfinite(cfg.du_max):
            step = cfg.du_max * cfg.sample_time
            u = min(max(u, self._last_out - step), self._last_out + step)
        return self._clip(u)

    def _direction(self) -> float:
        cfg = self.pid.config
        return -1.0 if (cfg.direct_action != (cfg.kp < 0)) else 1.0

    def _end(self, state: str, reason: str) -> None:
        """Leave the test: restore the gains from before it, PID resumes bumplessly from u0."""
        if self._saved_gains is not None:
            self.pid.set_gains(**self._saved_gains)
        if self._u0 is not None:
            self._pending = self._u0              # the bias: equilibrium input of the test
        elif self._pending is None:               # ended while settling: continue the last output
            last = self._last_out if self._last_out is not None else self.pid.output
            self._pending = 0.0 if last is None else last
        self._state = state
        self._reason = reason

    def _test_step(self, t: float, y: float, r: float) -> float | None:
        """One sample of settling/relay/measuring; None = let the PID act (settling, or the test ended)."""
        if not (math.isfinite(y) and math.isfinite(r)):
            self._end('failed', 'non-finite measurement or setpoint during the test')
            return None
        if math.isnan(self._t_start):
            self._t_start, self._r_test = t, r
        if r != self._r_test:
            self._end('failed', 'setpoint changed during the test')
            return None
        if self._state == 'settling':
            return self._settle(t, y, r)
        return self._relay(t, y, r)

    def _settle(self, t: float, y: float, r: float) -> float | None:
        cfg = self._cfg
        u = self._pid_step(y, r)
        self._win_t.append(t)
        self._win_y.append(y)
        self._win_u.append(u)
        while self._win_t and self._win_t[0] < t - cfg.settle_time - 1e-9:
            for window in (self._win_t, self._win_y, self._win_u):
                window.popleft()
        elapsed = t - self._t_start
        full = elapsed >= cfg.settle_time - 1e-9
        steady = full and all(abs(v - r) <= cfg.settle_band for v in self._win_y)
        if steady or elapsed >= cfg.settle_timeout:
            wy = np.array(self._win_y)
            self._u0 = float(np.mean(self._win_u))
            self._u0_start = self._u0
            self._sigma = float(np.std(np.diff(wy)) / math.sqrt(2.0)) if len(wy) > 2 else 0.0
            self._eps = max(cfg.hysteresis, cfg.noise_band * self._sigma)
            self._state = 'relay'
            self._t_start = t
            self._relay_high = r - y >= 0.0
            if self._amplitude() < 0.1 * self._cfg.relay_amplitude:
                self._end('failed', f'relay has no amplitude: the bias u0 = {self._u0:g} is within '
                                    f'10 % of autotune.relay_amplitude from an output limit')
                return None
            return self._relay(t, y, r)
        return u

    def _relay(self, t: float, y: float, r: float) -> float | None:
        cfg = self._cfg
        if cfg.max_amplitude > 0 and abs(y - r) > cfg.max_amplitude:
            self._end('failed', f'output amplitude |y − r| = {abs(y - r):g} above '
                                f'autotune.max_amplitude = {cfg.max_amplitude:g}')
            return None
        e = r - y      # relay in the frame of a positive-gain plant; the sign goes on u
        if e > self._eps:
            self._relay_high = True
        elif e < -self._eps:
            self._relay_high = False
        sign = 1.0 if self._relay_high else -1.0
        u = self._limit(self._u0 + self._direction() * sign * self._amplitude())
        switched = bool(self._rec_u) and (u != self._rec_u[-1])
        self._rec_t.append(t)
        self._rec_u.append(u)
        self._rec_y.append(y)
        if switched:
            self._analyse(r)
            if self._state not in TESTING:
                return None       # tuned (PID takes over from u0) or failed
        if t - self._t_start > cfg.timeout:
            what = 'no oscillation' if self._state == 'relay' else 'no stationary oscillation'
            self._end('failed', f'{what} within autotune.timeout = {cfg.timeout:g} s')
            return None
        return u

    def _analyse(self, r: float) -> bool:
        """At a relay switch: count cycles, correct the bias, identify and tune when enough are stationary."""
        cfg = self._cfg
        tt = np.array(self._rec_t)
        uu, ref = self._identification_input()
        yy = np.array(self._rec_y)
        cycles = [c for c in ident.relay_cycles(tt, uu, yy, ref) if c.start >= self._first_cycle]
        if not cycles:
            return False
        self._state = 'measuring'
        last = cycles[-1]
        if last.end != len(tt) - 1:
            return False      # this switch closed a half cycle only
        asym = [(c.high_time - c.low_time) / c.period for c in cycles[-2:]]
        if (cfg.bias_correction and len(asym) == 2 and min(abs(a) for a in asym) > cfg.asymmetry_tol
                and asym[0] * asym[1] > 0.0):     # two cycles in a row, same side: not noise
            seg = slice(last.start, last.end)
            self._u0 = float(np.mean(np.array(self._rec_u)[seg]))
            self._first_cycle = last.end
            self._cycles = 0
            return False
        self._cycles = len(cycles)
        slack = 2.0 * self.sample_time
        tail = ident.stationary_cycles(cycles, cfg.min_cycles, cfg.stationarity_tol, slack)
        if tail is None:
            return False
        try:
            res = ident.identify_relay(tt, uu, yy, self._u0_start, r, self._eps, cycles=tail,
                                       gain=cfg.process_gain or None, kind=cfg.model)
            gains = self._tune(res)
            sign = -1.0 if self.pid.config.kp < 0 else 1.0   # keep a reverse action by negative kp
            new = {'kp': sign * gains['kp'],
                   'ti': gains['ti'] if gains.get('ti') else math.inf,
                   'td': gains['td'] if gains.get('td') else 0.0,
                   'b': gains['b'] if gains.get('b') is not None else 1.0,
                   'c': gains['c'] if gains.get('c') is not None else 1.0}
            self.pid.set_gains(**new)
        except (ValueError, ArithmeticError) as exc:
            self._end('failed', f'identification/tuning failed: {exc}')
            return True
        self._result, self._gains = res, gains
        # The PID takes over from the bias u0, the equilibrium input, not from the last relay
        # value u0 ± d, which would disturb the loop by d.
        self._pending = self._u0
        self._state = 'tuned'
        self._reason = ''
        return True

    def _identification_input(self) -> tuple[np.ndarray, float]:
        """Recorded u as seen by a positive-gain plant and the current relay centre.

        Reverse-acting loops (negative plant gain) are mirrored around the initial bias.
        """
        uu = np.array(self._rec_u)
        if self._direction() < 0:
            return 2.0 * self._u0_start - uu, 2.0 * self._u0_start - self._u0
        return uu, self._u0

    def _tune(self, res: ident.RelayIdentification) -> dict[str, float | None]:
        from tank_control.core.tuning.rules import tune   # sibling package, imported when needed
        cfg = self._cfg
        if cfg.rule in RULES_ULTIMATE:
            ku, tu = (res.ku, res.tu) if cfg.method == 'first_harmonic' else (res.ku_df, res.tu_df)
            return dict(tune(cfg.rule, cfg.kind, ku=ku, tu=tu))
        model = res.model
        if cfg.rule in RULES_IPDT:
            if not isinstance(model, ident.IpdtModel):
                raise ValueError(f'autotune.rule: {cfg.rule} needs an integrating (IPDT) model, '
                                 f'the relay data gave {model.kind}')
            return dict(tune(cfg.rule, cfg.kind, gain=model.gain, dead_time=model.dead_time))
        if not isinstance(model, ident.FopdtModel):
            raise ValueError(f'autotune.rule: {cfg.rule} needs an FOPDT model, the relay data gave '
                             f'{model.kind}')
        return dict(tune(cfg.rule, cfg.kind, gain=model.gain, time_constant=model.time_constant,
                         dead_time=model.dead_time))


def _gain_fields(cfg: PidConfig) -> dict[str, Any]:
    return {'kp': cfg.kp, 'ti': cfg.ti, 'td': cfg.td, 'n': cfg.n, 'b': cfg.b, 'c': cfg.c}


def _scalar(value: Any, name: str) -> float:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != 1:
        raise ValueError(f'{name}: expected 1 value for the SISO relay auto-tuner, got {arr.size}')
    return float(arr[0])
