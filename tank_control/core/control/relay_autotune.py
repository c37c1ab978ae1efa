"""Relay auto-tuner: a PID that identifies its process with a relay test and tunes itself.

[DeadTimeNotes] §1.3 (Fig. 6.16, PID and on-off controller in parallel) and [Precup2013] §3.2–3.3, made safe to run
on a live loop: ``idle → settling → relay → measuring → proposed/tuned → running``, with
``failed`` / ``aborted`` / ``reverted`` restoring the previous gains bumplessly. The ultimate
point and model come from :func:`~tank_control.core.tuning.identification.identify_relay`, the
gains from :func:`~tank_control.core.tuning.rules.tune`; the identified model is kept, so a rule
or target change re-derives the proposal without a new test. Each proposal carries its margins
and predicted response (``core/analysis/robustness.py``); it is applied at once or previewed,
reverted on request and verified against its prediction after the apply. With
``autotune.transient_points`` the relay runs on until its record from rest gives ``G(jω)`` at
several frequencies ([Precup2013] eqs. 3.3.1–3.3.10, :func:`transient_plan`). Times in s, signals in
the loop's units. States, faults, preview/apply/revert/verify: docs/controllers.md
("relay_autotune").
"""
from __future__ import annotations

import copy
import math
import multiprocessing
import threading
from collections import deque
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures import wait as futures_wait
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from tank_control.core.analysis.robustness import (LoopReport, Prediction, finite_or,
                                                   loop_report, predict)
from tank_control.core.analysis.step_metrics import iae, step_metrics
from tank_control.core.control.autotune_machine import AutotuneMachine
from tank_control.core.control.pid import PidConfig, Pid2Dof
from tank_control.core.params import check_config, param
from tank_control.core.tuning import identification as ident
from tank_control.core.tuning.model import DiscretePlant, ProcessModel, from_identified

STATES = ('idle', 'settling', 'relay', 'step', 'measuring', 'tuned', 'running', 'proposed',
          'reverted', 'failed', 'aborted', 'waiting', 'process_gain')
"""The tuner's states; ``waiting`` and ``process_gain`` are the auto-tuned Smith predictor's
(core/control/smith_autotune.py), which reports through the same ``autotune.state``."""
TESTING = ('settling', 'relay', 'step', 'measuring')
RULES_ULTIMATE = ('zn', 'zn_001', 'zn_004_q0', 'zn_004_q1')
RULES_IPDT = ('mdp', 'experimental')
RULES_FOPDT = ('oppelt', 'cohen_coon')
RULES_MODEL = ('ms', 'amigo', 'simc', 'lambda', 'ho', 'tan', 'wang')
RULES = RULES_ULTIMATE + RULES_IPDT + RULES_FOPDT + RULES_MODEL
DESIGN_FIELDS = ('rule', 'kind', 'ms_target', 'tau_c', 'gain_margin', 'phase_margin', 'method')
"""Settings a design depends on: a change re-derives the gains from the stored model."""
MODEL_METHODS = ('none', 'harmonic', 'time_domain', 'eq_3_6_2', 'eq_3_3_15', 'two_points',
                 'step_tangent', 'step_two_point')
VERIFY_STATES = ('none', 'waiting', 'measuring', 'ok', 'worse', 'cancelled')


_BIG = 1e12
TRANSIENT_MAX_RATIO = 5.0
"""Highest transient point, in units of ωc (the lag window's correction grows as
e^((ω·Tu/20)²/2))."""
TRANSIENT_MAX_DRIFT = 0.002
"""Largest output drift at the relay's start, per Tu and relay output amplitude a, that the
transient points accept: the points' error grew as ≈ 10·(drift·Tu/a) in % on [DeadTimeNotes]'s FOPDT
(docs/tuning.md); above it (and above 6 standard errors of the slope: the loop's response to
the noise makes the samples correlated, and 3 errors were exceeded at rest) they are skipped."""
TRANSIENT_CHECK_WARN = 0.05
"""Above this relative difference between the transient estimate and the first harmonic at the
oscillation frequency, ``autotune.warning`` says so."""
TRANSIENT_MAX_ALPHA_H = 8.0
"""Largest α·horizon: the unweighting e^(α·t) amplifies the noise of the pulse response; on
[DeadTimeNotes]'s FOPDT with 1 % noise the points were within 10 % at α·H = 2…8 and useless at 15
(docs/tuning.md)."""


def autotune_param(default: Any, description: str, field_name: str, **meta: Any) -> Any:
    """A field declared as the parameter ``autotune.<field_name>`` (every auto-tuner's)."""
    return param(default, description, name='autotune.' + field_name, **meta)


_at = autotune_param


@dataclass(frozen=True)
class AutotuneConfig:
    """Settings of the relay test; each field is the parameter ``autotune.<field>``."""

    test: str = _at('relay', 'the identification test: relay ([Precup2013] §3.2–3.3) or step: an '
                    'open-loop step of autotune.step_size from the settled bias u0 in manual '
                    'mode, held until the output is steady, FOPDT by autotune.step_method '
                    '([DeadTimeNotes] §1.2.1)', 'test', choices=('relay', 'step'))
    step_size: float = _at(1.0, 'step test: input change Δu from u0 (signed as the loop acts: '
                           'positive raises the output)', 'step_size', unit='u units',
                           min=-_BIG, max=_BIG, source='[DeadTimeNotes] eq. 6.15')
    step_method: str = _at('tangent', 'step test: tangent of steepest slope ([DeadTimeNotes] eq. 6.15) or '
                           'two_point (28.3 % and 63.2 % times)', 'step_method',
                           choices=ident.STEP_METHODS)
    relay_amplitude: float = _at(1.0, 'relay amplitude d around the bias u0', 'relay_amplitude',
                                 unit='u units', min=1e-9, max=_BIG,
                                 source='[DeadTimeNotes] eq. 6.22, [Precup2013] eq. 3.2.1')
    relay_bias: float = _at(0.0, 'relay bias μ0: the relay switches between u0 + μ0 ± d ([Precup2013] eq. '
                            '3.3.12, in the frame of a positive-gain plant); the asymmetric cycle '
                            'gives the static gain kP ([Precup2013] eq. 3.3.13) and the FOPDT of [Precup2013] eqs. '
                            '3.3.14–3.3.17; |μ0| must stay below relay_amplitude; 0 = symmetric '
                            'relay', 'relay_bias', unit='u units', min=-_BIG, max=_BIG,
                            source='[Precup2013] eqs. 3.3.12–3.3.17')
    additional_relay: float = _at(0.0, 'amplitude ratio ρ of the additional relay ([Precup2013] eq. '
                                  '3.3.18): ±ρ·d added to the relay output, changing sign at '
                                  'every upward switch of the relay, so that the oscillation '
                                  'also holds 0.5·ωc, 1.5·ωc; G(j0.5ωc) becomes point2 and, '
                                  'with autotune.model sopdt, the second point of the SOPDT '
                                  'without the integrator phase; [Precup2013] recommends 0.1–0.3; 0 = '
                                  'off', 'additional_relay', unit='-', min=0.0, max=0.5,
                                  source='[Precup2013] eqs. 3.3.18–3.3.21')
    transient_points: tuple[float, ...] = _at(
        (0.0,), 'frequencies ω/ωc (ωc = 2π/Tu of this test) at which G(jω) is computed from the '
        'recorded relay transient with the decaying exponential ([Precup2013] eqs. 3.3.1–3.3.10): the '
        'relay runs on after the stationary cycles until the record from its start is '
        'transient_horizon + 4/transient_alpha long; results autotune.transient_*; [0] = off',
        'transient_points', unit='ωc', min=0.0, max=TRANSIENT_MAX_RATIO,
        source='[Precup2013] eqs. 3.3.1–3.3.10')
    transient_horizon: float = _at(0.0, 'transient points: cut of the pulse response (after it '
                                   'has died out); 0 = from the identified model: L + 7·T '
                                   '(FOPDT; T1 + T2 for an SOPDT), L + Tu/4 (IPDT)',
                                   'transient_horizon', unit='s', min=0.0, max=_BIG)
    transient_alpha: float = _at(0.0, 'transient points: decay rate α of the weighting '
                                 'e^(−α·t); 0 = 4/transient_horizon; α·horizon above '
                                 f'{TRANSIENT_MAX_ALPHA_H:g} amplifies the noise too much',
                                 'transient_alpha', unit='1/s', min=0.0, max=_BIG,
                                 source='[Precup2013] eqs. 3.3.1–3.3.2')
    hysteresis: float = _at(0.0, 'relay hysteresis ε (noise band, [Precup2013] Fig. 3.3); the larger of '
                            'this and noise_band·σ is used', 'hysteresis', unit='y units',
                            min=0.0, max=_BIG)
    noise_band: float = _at(4.0, 'automatic hysteresis in units of the noise standard deviation '
                            'σ estimated while settling; 0 = off', 'noise_band', unit='-',
                            min=0.0, max=100.0)
    bias_correction: bool = _at(True, 'move the relay bias u0 to the mean input of a cycle whose '
                                'half-periods are asymmetric (symmetric relay only: not with '
                                'relay_bias)', 'bias_correction')
    asymmetry_tol: float = _at(0.1, '|Tu1 − Tu2|/period above which the bias is corrected',
                               'asymmetry_tol', unit='-', min=0.0, max=1.0)
    min_cycles: int = _at(4, 'stationary relay periods used for identification ([Precup2013] §3.3: at '
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
    method: str = _at('first_harmonic', 'ultimate point used for tuning: first_harmonic ([Precup2013] '
                      'eqs. 3.3.19–3.3.21, corrected to −180°) or describing_function ([DeadTimeNotes] eq. '
                      '6.22)', 'method', choices=('first_harmonic', 'describing_function'))
    model: str = _at('auto', 'model identified from the relay data ([Precup2013] §3.3, 3.6.2); sopdt: '
                     'after the relay, a second relay phase with an integrator in series finds '
                     'the −90° point, and the SOPDT goes through both points ([Precup2013] §3.3 intro, '
                     'eqs. 3.5.8–3.5.14)', 'model', choices=('auto', 'fopdt', 'ipdt', 'sopdt'))
    process_gain: float = _at(0.0, 'known static gain kP for the FOPDT model ([Precup2013] eq. 3.6.2); '
                              '0 = identify', 'process_gain', unit='y units per u unit',
                              min=0.0, max=_BIG)
    rule: str = _at('zn_001', 'tuning rule: zn / zn_001 / zn_004_q0 / zn_004_q1 from ku, tu; mdp / '
                    'experimental from the IPDT model; oppelt / cohen_coon from the FOPDT model; '
                    'ms (largest integral gain with Ms <= autotune.ms_target on the implemented '
                    'loop), amigo, simc, lambda, ho, tan, wang from the identified model (see '
                    'core/tuning/rules.py); a change re-derives the gains from the stored model',
                    'rule', choices=RULES)
    kind: str = _at('pid', 'controller type the rule designs', 'kind', choices=('p', 'pi', 'pid'))
    ms_target: float = _at(1.4, 'rule ms: the sensitivity peak Ms the design may reach',
                           'ms_target', unit='-', min=1.05, max=5.0, source='[Precup2013] eq. 3.4.7')
    tau_c: float = _at(0.0, "rules simc, lambda: desired closed-loop time constant (0 = the rule's "
                       'default)', 'tau_c', unit='s', min=0.0, max=_BIG)
    gain_margin: float = _at(0.0, 'rules ho, tan: gain margin A_r (0 = 3)', 'gain_margin',
                             unit='-', min=0.0, max=100.0, source='[Precup2013] eqs. 3.4.17, 3.4.22')
    phase_margin: float = _at(0.0, 'rule ho: phase margin (0 = 60)', 'phase_margin', unit='deg',
                              min=0.0, max=89.0, source='[Precup2013] eq. 3.4.18')
    design_time: float = _at(0.0, 'time the identification and design of a relay test may take '
                             'off the sampling path: the relay keeps running meanwhile and the '
                             'result takes effect at the first sample this long after the '
                             "test's data were complete (the same sample in lockstep, sim and "
                             'in-process runs: a sample waits only if the work is not done by '
                             'then); 0 = at once, on the sampling path. clock_mode wall: always '
                             'in the worker, taken at the first sample at least this long after '
                             'at which it is ready (no sample waits)', 'design_time', unit='s', min=0.0, max=3600.0)
    apply: str = _at('auto', 'auto: the tuned gains take over at the end of the test; preview: '
                     'they are proposed (autotune.proposed_*, predicted margins and response) and '
                     'applied by the ~/apply_autotune service or autotune.apply_time', 'apply',
                     choices=('auto', 'preview'))
    apply_time: float = _at(0.0, 'apply a pending proposal at the first sample at or after this '
                            "time (the loop's time), once; 0 = only by the service",
                            'apply_time', unit='s', min=0.0, max=_BIG)
    verify_step: float = _at(0.0, 'after an apply: a setpoint step of this size added by the '
                             'controller for the verification window (then removed), measured '
                             'against its prediction; 0 = verify on the next setpoint change',
                             'verify_step', unit='y units', min=-_BIG, max=_BIG)
    verify_window: float = _at(0.0, 'length of the verified response; 0 = twice the predicted '
                               'settling time, at least 4 Tu', 'verify_window', unit='s',
                               min=0.0, max=_BIG)
    verify_tolerance: float = _at(1.5, 'a measured IAE above this times the predicted one (or '
                                  'overshoot above this times the predicted + 5 points) is '
                                  'reported as a warning', 'verify_tolerance', unit='-',
                                  min=1.0, max=100.0)
    start_time: float = _at(0.0, "start a test at the first sample at or after this time (the "
                            "loop's simulated time), once; 0 = no scheduled start. Lets an "
                            'in-process run and a lockstep ROS run start at the same sample',
                            'start_time', unit='s', min=0.0, max=_BIG)

    def reason(self) -> str | None:
        """Why the settings do not fit together (None if they do)."""
        if self.test == 'step' and self.step_size == 0.0:
            return 'autotune.step_size: a step test needs a non-zero step'
        if self.test == 'step' and self.model not in ('auto', 'fopdt'):
            return (f'autotune.model: {self.model} cannot come from a step test (it gives an '
                    'FOPDT); use auto or fopdt')
        if self.additional_relay > 0.0 and self.relay_bias != 0.0:
            return ('autotune.additional_relay: not with a biased relay (autotune.relay_bias '
                    f'{self.relay_bias:g}): each needs the cycle the other changes')
        reason = self._transient_reason()
        if reason:
            return reason
        if abs(self.relay_bias) >= self.relay_amplitude:
            return (f'autotune.relay_bias: |{self.relay_bias:g}| must be below '
                    f'autotune.relay_amplitude {self.relay_amplitude:g}: the relay output would '
                    'not change sides around u0 and no cycle forms ([Precup2013] eq. 3.3.12)')
        return None

    @property
    def transient(self) -> bool:
        """Transient points requested (``autotune.transient_points`` not [0])."""
        return any(p > 0.0 for p in self.transient_points)

    def _transient_reason(self) -> str | None:
        points = self.transient_points
        if not self.transient:
            return None
        if 0.0 in points or len(points) > 20:
            return (f'autotune.transient_points: {list(points)}: [0] (off) or 1 to 20 '
                    f'frequencies ω/ωc in (0, {TRANSIENT_MAX_RATIO:g}]')
        if self.test == 'step':
            return ('autotune.transient_points: come from the relay record; the step test '
                    '(autotune.test step) has none')
        if self.model == 'sopdt' and self.additional_relay == 0.0:
            return ('autotune.transient_points: not with autotune.model sopdt through the '
                    'integrator phase (the record must be one relay test from rest); use '
                    'autotune.additional_relay for the second point')
        if (self.transient_alpha > 0.0 and self.transient_horizon > 0.0
                and self.transient_alpha * self.transient_horizon > TRANSIENT_MAX_ALPHA_H):
            return (f'autotune.transient_alpha: α·horizon = '
                    f'{self.transient_alpha * self.transient_horizon:g} > '
                    f'{TRANSIENT_MAX_ALPHA_H:g}: the unweighting e^(α·t) would amplify the '
                    'noise of the pulse response beyond use; lower transient_alpha (and '
                    'record longer) or the horizon')
        return None


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
    ku_df: float = _at(0.0, 'describing-function Ku = 4d/(πa) ([DeadTimeNotes] eq. 6.22)', 'ku_df', min=0.0,
                       max=_BIG, read_only=True)
    tu_df: float = _at(0.0, 'mean relay period', 'tu_df', unit='s', min=0.0, max=_BIG,
                       read_only=True)
    model_kind: str = _at('none', 'identified model', 'model_kind',
                          choices=('none', 'fopdt', 'ipdt', 'sopdt'), read_only=True)
    model_method: str = _at('none', 'how the model was found: time_domain (fit on the relay '
                            'record), eq_3_6_2 (known static gain, [Precup2013] eq. 3.6.2), eq_3_3_15 '
                            '(biased relay, [Precup2013] eqs. 3.3.13–3.3.17), two_points (SOPDT through '
                            'the −180° and −90° points, [Precup2013] eqs. 3.5.8–3.5.14)', 'model_method',
                            choices=MODEL_METHODS, read_only=True)
    model_gain: float = _at(0.0, 'model gain K (FOPDT) or k1 (IPDT, per s)', 'model_gain',
                            min=-_BIG, max=_BIG, read_only=True)
    model_time_constant: float = _at(0.0, 'model time constant T', 'model_time_constant',
                                     unit='s', min=0.0, max=_BIG, read_only=True)
    model_dead_time: float = _at(0.0, 'model dead time L or To', 'model_dead_time', unit='s',
                                 min=0.0, max=_BIG, read_only=True)
    model_time_constant2: float = _at(0.0, 'second (smaller) time constant T2 of an SOPDT model',
                                      'model_time_constant2', unit='s', min=0.0, max=_BIG,
                                      read_only=True)
    point2_omega: float = _at(0.0, 'frequency of the second point of an SOPDT fit (autotune.model '
                              'sopdt): the ≈ −90° point of the relay with an integrator, or 0.5·ωc '
                              'of the additional relay; 0 = none', 'point2_omega', unit='rad/s',
                              min=0.0, max=_BIG, read_only=True)
    point2_gain: float = _at(0.0, 'process gain |G| at point2_omega', 'point2_gain',
                             unit='y units per u unit', min=0.0, max=_BIG, read_only=True)
    point2_phase: float = _at(0.0, 'process phase at point2_omega', 'point2_phase', unit='deg',
                              min=-_BIG, max=_BIG, read_only=True)
    transient_omega: tuple[float, ...] = _at((0.0,), 'frequencies of the transient points '
                                             '(autotune.transient_points·ωc); [0] = none',
                                             'transient_omega', unit='rad/s', min=0.0,
                                             max=_BIG, read_only=True)
    transient_gain: tuple[float, ...] = _at((0.0,), '|G(jω)| at transient_omega ([Precup2013] eqs. '
                                            '3.3.1–3.3.10), in the frame of a positive-gain '
                                            'plant like model_gain', 'transient_gain',
                                            unit='y units per u unit', min=0.0, max=_BIG,
                                            read_only=True)
    transient_phase: tuple[float, ...] = _at((0.0,), 'arg G(jω) at transient_omega',
                                             'transient_phase', unit='deg', min=-_BIG,
                                             max=_BIG, read_only=True)
    transient_alpha_used: float = _at(0.0, 'α the transient points used', 'transient_alpha_used',
                                      unit='1/s', min=0.0, max=_BIG, read_only=True)
    transient_horizon_used: float = _at(0.0, 'cut of the pulse response the transient points '
                                        'used', 'transient_horizon_used', unit='s', min=0.0,
                                        max=_BIG, read_only=True)
    transient_record: float = _at(0.0, 'length of the relay record the transient points came '
                                  'from (from the relay start)', 'transient_record', unit='s',
                                  min=0.0, max=_BIG, read_only=True)
    transient_check: float = _at(0.0, 'the same estimate at the oscillation frequency against '
                                 'the first harmonic over the stationary cycles, |Ĝ/G1 − 1| '
                                 f'(above {100 * TRANSIENT_CHECK_WARN:g} % autotune.warning '
                                 'says so)', 'transient_check', unit='%', min=0.0, max=_BIG,
                                 read_only=True)
    proposed_kp: float = _at(0.0, 'gains of the design from the identified model (autotune.rule)',
                             'proposed_kp', min=0.0, max=_BIG, read_only=True)
    proposed_ti: float = _at(0.0, 'proposed integral time (0 = none)', 'proposed_ti', unit='s',
                             min=0.0, max=_BIG, read_only=True)
    proposed_td: float = _at(0.0, 'proposed derivative time', 'proposed_td', unit='s', min=0.0,
                             max=_BIG, read_only=True)
    proposed_b: float = _at(1.0, 'proposed setpoint weight b', 'proposed_b', min=0.0, max=1.0,
                            read_only=True)
    proposed_c: float = _at(1.0, 'proposed setpoint weight c', 'proposed_c', min=0.0, max=1.0,
                            read_only=True)
    proposed_stable: bool = _at(False, 'proposed loop stable on the model', 'proposed_stable',
                                read_only=True)
    proposed_ms: float = _at(0.0, 'Ms of the proposed loop on the model (implemented discrete '
                             'loop)', 'proposed_ms', min=0.0, max=_BIG, read_only=True)
    proposed_gain_margin: float = _at(0.0, 'gain margin of the proposed loop (0 = infinite)',
                                      'proposed_gain_margin', min=0.0, max=_BIG, read_only=True)
    proposed_phase_margin: float = _at(0.0, 'phase margin of the proposed loop',
                                       'proposed_phase_margin', unit='deg', min=-_BIG, max=_BIG,
                                       read_only=True)
    predicted_overshoot: float = _at(0.0, 'predicted overshoot of a setpoint step (simulated on '
                                     'the model)', 'predicted_overshoot', unit='%', min=0.0,
                                     max=_BIG, read_only=True)
    predicted_iae_setpoint: float = _at(0.0, 'predicted IAE of a unit setpoint step',
                                        'predicted_iae_setpoint', unit='y units*s', min=0.0,
                                        max=_BIG, read_only=True)
    predicted_iae_load: float = _at(0.0, 'predicted IAE of a unit load step at the plant input',
                                    'predicted_iae_load', unit='y units*s', min=0.0, max=_BIG,
                                    read_only=True)
    verify_state: str = _at('none', 'verification of the applied gains: waiting (for a setpoint '
                            'change or the verification step), measuring, ok, worse (than '
                            'predicted), cancelled', 'verify_state', choices=VERIFY_STATES,
                            read_only=True)
    verify_step_size: float = _at(0.0, 'size of the verified setpoint step', 'verify_step_size',
                                  unit='y units', min=-_BIG, max=_BIG, read_only=True)
    verify_overshoot_measured: float = _at(0.0, 'measured overshoot of the verified step',
                                           'verify_overshoot_measured', unit='%', min=0.0,
                                           max=_BIG, read_only=True)
    verify_overshoot_predicted: float = _at(0.0, 'predicted overshoot of the verified step',
                                            'verify_overshoot_predicted', unit='%', min=0.0,
                                            max=_BIG, read_only=True)
    verify_iae_measured: float = _at(0.0, 'measured IAE over the verification window',
                                     'verify_iae_measured', unit='y units*s', min=0.0, max=_BIG,
                                     read_only=True)
    verify_iae_predicted: float = _at(0.0, 'predicted IAE over the verification window',
                                      'verify_iae_predicted', unit='y units*s', min=0.0,
                                      max=_BIG, read_only=True)
    warning: str = _at('', 'non-empty when the verified response was much worse than predicted '
                       '(the numbers) or a proposal was not applied (why)', 'warning',
                       read_only=True)


@dataclass(frozen=True)
class Proposal:
    """A design from the identified model: the PID fields it sets (``kp`` signed as the
    running PID's, ``ti`` inf for none), the rule's raw result, its robustness ``report`` and
    predicted ``prediction`` on the model (implemented discrete loop)."""

    gains: dict[str, float]
    tuned: dict[str, float | None]
    report: LoopReport
    prediction: Prediction


@dataclass(frozen=True)
class TransientPlan:
    """How the transient points are computed (:func:`transient_plan`): ``alpha`` [1/s],
    ``horizon`` (cut of the pulse response) [s], ``smoothing`` (Gaussian lag window) [s] and the
    ``record`` length from the relay's start that it needs [s]."""

    alpha: float
    horizon: float
    smoothing: float
    record: float


@dataclass(frozen=True)
class TransientPoints:
    """``G(jω)`` at ``omega`` [rad/s] from the relay transient, with the ``alpha`` [1/s],
    ``horizon`` [s] and ``record`` length [s] it came from."""

    omega: np.ndarray
    response: np.ndarray
    alpha: float
    horizon: float
    record: float
    phase: np.ndarray
    """arg G(jω) [rad] on the branch of the identified model's phase (below −π where it lags
    more), not wrapped into (−π, π]."""
    check: float
    """|Ĝ(jω1)/G1 − 1| of the same estimate at the oscillation frequency ω1 against the first
    harmonic G1 over the stationary cycles [-]."""


def transient_plan(model: ident.Model | ident.SopdtModel, tu: float,
                   cfg: AutotuneConfig) -> TransientPlan:
    """α, cut, lag window and record length of the transient points ([Precup2013] eqs. 3.3.1–3.3.10;
    the choices are ours, measured in docs/tuning.md): the cut where the pulse response has died
    out, ``L + 7·T`` for a lag (``T1 + T2`` for an SOPDT; e^(−7) ≈ 0.1 % left) and ``L + Tu/4``
    for an integrator (its differenced output's pulse ends at L); α = 4/cut (the unweighting
    then amplifies by e^4 at most); the record from the relay's start ``cut + 4/α`` (the
    weighted record has decayed to e^(−4) past the cut); the lag window ``Tu/20``.
    ``transient_horizon``/``transient_alpha`` > 0 replace the cut/α."""
    smoothing = tu / 20.0
    if isinstance(model, ident.IpdtModel):
        auto = model.dead_time + 5.0 * smoothing
    elif isinstance(model, ident.SopdtModel):     # T1 + T2, or 1/(ζ·ωn) when underdamped
        auto = model.dead_time + 7.0 * max(model.b / model.c, 2.0 * model.a / model.b)
    else:
        auto = model.dead_time + 7.0 * model.time_constant
    horizon = cfg.transient_horizon or auto
    alpha = cfg.transient_alpha or 4.0 / horizon
    if alpha * horizon > TRANSIENT_MAX_ALPHA_H:
        raise ValueError(f'autotune.transient_alpha: α·horizon = {alpha * horizon:.3g} > '
                         f'{TRANSIENT_MAX_ALPHA_H:g} (horizon {horizon:.4g} s): the unweighting '
                         'would amplify the noise beyond use; lower transient_alpha')
    return TransientPlan(alpha, horizon, smoothing, horizon + 4.0 / alpha)


@dataclass
class _Check:
    """Verification of applied gains (see the module docstring)."""

    state: str = 'none'
    window: float = 0.0
    r_prev: float | None = None
    r_base: float = 0.0
    r_new: float = 0.0
    step: float = 0.0
    offset: float = 0.0
    t0: float = 0.0
    y0: float = 0.0
    t: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)
    overshoot_predicted: float = 0.0
    iae_predicted: float = 0.0
    overshoot_measured: float = 0.0
    iae_measured: float = 0.0
    calm_since: float | None = None


class RelayAutotuner(AutotuneMachine):
    """SISO Controller (core/interfaces.py): a :class:`Pid2Dof` with a relay auto-tuning test.

    ``pid_config``: the PID in normal operation (its limits bound the relay too);
    ``autotune``: the test settings. Channels: reads ``output_name``, writes ``input_name``.
    Designed to be driven by a node: ``start()``/``abort()`` return ``(accepted, message)``
    (a std_srvs/Trigger answer), ``state``/``status`` are plain values; ``status['state']``
    and, after ``failed``/``aborted``, ``status['reason']``.
    """

    disturbance_names: tuple[str, ...] = ()
    TESTING = TESTING

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
        self._apply_done = False                # autotune.apply_time has fired
        self._model: ProcessModel | None = None   # the identified model, kept
        self._transient: TransientPoints | None = None
        self._proposal: Proposal | None = None
        self._warning = ''
        self._check = _Check()
        self.ms_max = 0.0
        """Bound on Ms of an applied design (``robustness.ms_max``; 0 = none)."""
        self.wall_clock = False
        """Samples paced by the wall clock (controller_node in ``wall`` mode): the
        identification and design always run in the worker thread and their result is taken
        at the first sample at least ``autotune.design_time`` after the data were complete at
        which it is ready; a sample never waits for it. False (in-process, lockstep, sim): at
        that sample exactly (waiting if need be), or inline with ``design_time`` 0."""
        self._clear_test()

    # ------------------------------------------------------------------ API
    @property
    def sample_time(self) -> float:
        return self.pid.config.sample_time

    @property
    def config(self) -> AutotuneConfig:
        return self._cfg

    @property
    def result(self) -> ident.RelayIdentification | None:
        """The identification of the last successful test."""
        return self._result

    @property
    def model(self) -> ProcessModel | None:
        """The process model identified by the last successful test (kept)."""
        return self._model

    @property
    def proposal(self) -> Proposal | None:
        """The design from the identified model under the current settings."""
        return self._proposal

    def configure(self, autotune: AutotuneConfig) -> None:
        """Replace the test settings (not while a test runs: ValueError). A change of a design
        setting (:data:`DESIGN_FIELDS`) re-derives the proposal from the stored model and, with
        ``apply`` auto, applies it; a design the model does not allow raises ValueError and
        leaves everything unchanged."""
        if self._state in TESTING:
            raise ValueError('autotune: settings cannot change while a test is running; abort it first')
        self._check_config(autotune)
        result = self._result
        redesign = any(getattr(autotune, name) != getattr(self._cfg, name)
                       for name in DESIGN_FIELDS)
        proposal = self._design(result, autotune) if result is not None and redesign else None
        if autotune.start_time != self._cfg.start_time:
            self._scheduled_done = False          # a new scheduled start is armed
        if autotune.apply_time != self._cfg.apply_time:
            self._apply_done = False
        self._cfg = autotune
        if proposal is not None:
            self._proposal = proposal
            self._offer(proposal)

    def refusal(self, proposal: Proposal) -> str:
        """Why ``proposal`` may not run ('' if it may): unstable on the model, or Ms above
        ``ms_max``."""
        rep = proposal.report
        if not rep.stable:
            return f'the proposed loop is unstable on the model {rep.model}'
        if self.ms_max > 0 and rep.ms > self.ms_max:
            return (f'Ms would be {rep.ms:.3g} > robustness.ms_max {self.ms_max:g} on the model '
                    f'{rep.model}')
        return ''

    # operator requests: AutotuneMachine; its hooks
    def _begin(self) -> tuple[bool, str]:
        """A test from idle, running, tuned, failed or aborted: settle first."""
        if self.wall_clock:
            _wall_pool().submit(_warm)            # the process starts while the test runs
        self._saved_gains = _gain_fields(self.pid.config)
        self._clear_test()
        self._cancel_check()
        self._state = 'settling'
        self._reason = ''
        return True, 'autotune: test started (settling)'

    def _has_proposal(self) -> bool:
        return self._proposal is not None

    def _apply_refusal(self) -> str:
        assert self._proposal is not None
        return self.refusal(self._proposal)

    def _apply_proposal(self) -> str:
        """The proposal's gains, bumplessly, and the verification armed."""
        assert self._proposal is not None
        self.pid.set_gains(**self._proposal.gains)
        self._state, self._reason, self._warning = 'running', '', ''
        self._arm_check()
        g = self._proposal.gains
        return (f"applied kp {abs(g['kp']):.4g}, ti {g['ti']:.4g} s, "
                f"td {g['td']:.4g} s (predicted Ms {self._proposal.report.ms:.3g})")

    def _has_saved(self) -> bool:
        return self._saved_gains is not None

    def _restore_saved(self) -> None:
        assert self._saved_gains is not None
        self.pid.set_gains(**self._saved_gains)
        self._cancel_check()

    def results(self) -> dict[str, Any]:
        """Parameter values the tuner produced (see :class:`AutotuneResults`), the PID's
        gains in parameter convention (ti = 0: no integral action) and ``autotune.start`` = False
        (so a node re-arms its start parameter)."""
        res = self._result
        model = self._model if res else None     # the ProcessModel the design used
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
            'autotune.model_method': res.model_method if res else 'none',
            'autotune.model_gain': float(model.gain) if model else 0.0,
            'autotune.model_time_constant': float(model.time_constant) if model else 0.0,
            'autotune.model_dead_time': float(model.dead_time) if model else 0.0,
            'autotune.model_time_constant2': float(model.time_constant2) if model else 0.0,
            'autotune.point2_omega': float(res.point_2[0]) if res and res.point_2 else 0.0,
            'autotune.point2_gain': float(abs(res.point_2[1])) if res and res.point_2 else 0.0,
            'autotune.point2_phase': float(np.degrees(np.angle(res.point_2[1])))
            if res and res.point_2 else 0.0,
            **self._transient_values(),
            'kp': abs(cfg.kp), 'ti': cfg.ti if math.isfinite(cfg.ti) else 0.0, 'td': cfg.td,
            'b': cfg.b, 'c': cfg.c,
            **self._proposal_values(), **self._check_values(),
            'autotune.warning': self._warning,
        }

    @property
    def transient(self) -> TransientPoints | None:
        """The transient points of the last successful test (None without)."""
        return self._transient if self._result is not None else None

    def _transient_values(self) -> dict[str, Any]:
        tp = self.transient
        if tp is None:
            return {'autotune.transient_omega': [0.0], 'autotune.transient_gain': [0.0],
                    'autotune.transient_phase': [0.0], 'autotune.transient_alpha_used': 0.0,
                    'autotune.transient_horizon_used': 0.0, 'autotune.transient_record': 0.0,
                    'autotune.transient_check': 0.0}
        return {'autotune.transient_omega': [float(w) for w in tp.omega],
                'autotune.transient_gain': [float(abs(g)) for g in tp.response],
                'autotune.transient_phase': [float(np.degrees(p)) for p in tp.phase],
                'autotune.transient_alpha_used': tp.alpha,
                'autotune.transient_horizon_used': tp.horizon,
                'autotune.transient_record': tp.record,
                'autotune.transient_check': 100.0 * tp.check}

    def _proposal_values(self) -> dict[str, Any]:
        p = self._proposal
        if p is None:
            return {'autotune.proposed_kp': 0.0, 'autotune.proposed_ti': 0.0,
                    'autotune.proposed_td': 0.0, 'autotune.proposed_b': 1.0,
                    'autotune.proposed_c': 1.0, 'autotune.proposed_stable': False,
                    'autotune.proposed_ms': 0.0, 'autotune.proposed_gain_margin': 0.0,
                    'autotune.proposed_phase_margin': 0.0, 'autotune.predicted_overshoot': 0.0,
                    'autotune.predicted_iae_setpoint': 0.0, 'autotune.predicted_iae_load': 0.0}
        g, rep, pred = p.gains, p.report, p.prediction
        return {'autotune.proposed_kp': abs(g['kp']),
                'autotune.proposed_ti': g['ti'] if math.isfinite(g['ti']) else 0.0,
                'autotune.proposed_td': g['td'], 'autotune.proposed_b': g['b'],
                'autotune.proposed_c': g['c'], 'autotune.proposed_stable': rep.stable,
                'autotune.proposed_ms': finite_or(rep.ms),
                'autotune.proposed_gain_margin': finite_or(rep.gain_margin),
                'autotune.proposed_phase_margin': finite_or(rep.phase_margin),
                'autotune.predicted_overshoot': finite_or(pred.overshoot),
                'autotune.predicted_iae_setpoint': finite_or(pred.iae_setpoint),
                'autotune.predicted_iae_load': finite_or(pred.iae_load)}

    def _check_values(self) -> dict[str, Any]:
        c = self._check
        return {'autotune.verify_state': c.state, 'autotune.verify_step_size': c.step,
                'autotune.verify_overshoot_measured': c.overshoot_measured,
                'autotune.verify_overshoot_predicted': c.overshoot_predicted,
                'autotune.verify_iae_measured': c.iae_measured,
                'autotune.verify_iae_predicted': c.iae_predicted}

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
        if (self._cfg.apply_time > 0 and not self._apply_done
                and float(t) >= self._cfg.apply_time - 1e-9):
            self._apply_done = True
            if self._state == 'proposed':
                self.apply()
        u = None
        if self._state in TESTING:
            u = self._test_step(float(t), yv, rv)
        elif self._state == 'tuned':
            self._state = 'running'
        if u is None:
            r_used = self._verify_sample(float(t), yv, rv) if self._state not in TESTING else rv
            u = self._limit(self._pid_step(yv, r_used))
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
        self._job: _Job | None = None  # identification + design running off the sampling path
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
        self._integrating = False              # the second phase: relay with an integrator
        self._first: ident.RelayIdentification | None = None   # the −180° phase's result
        self._rate = 0.0                       # integrator rate [u units/s]
        self._u_int = 0.0                      # integrator output [u units]
        self._rec_s: list[float] = []          # relay sign before the integrator
        self._y_rest = math.nan                # mean output over the settling window
        self._u2: float | None = None          # additional relay's output [u units]
        self._last_sign = 0.0                  # the relay's state at the previous sample
        self._from_rest = False                # settling ended steady (not by its timeout)
        self._transient_note = ''              # why a test has no transient points
        self._drift = (0.0, 0.0)               # output slope over the settling window, its SE
        self._held: tuple[ident.RelayIdentification, TransientPlan] | None = None
        """Identified, the relay running on for the transient record."""

    def _pid_step(self, y: float, r: float) -> float:
        if self._pending is not None:
            if not (math.isfinite(y) and math.isfinite(r)):
                return self._clip(self._pending)
            self.pid.reset(r, y, self._pending)
            self._pending = None
        return self.pid.update(r, y)

    def _clip(self, u: float) -> float:
        u_min, u_max = self.pid.limits
        return min(max(u, u_min), u_max)

    @property
    def _bias(self) -> float:
        """u0, the relay's or the step's bias [u units]: known once the settling window ended
        (every phase that reads it comes after)."""
        assert self._u0 is not None, 'no bias before the settling window'
        return self._u0

    @property
    def _bias_start(self) -> float:
        """u0 when the test left rest (the frame of the identification) [u units]."""
        assert self._u0_start is not None, 'no bias before the settling window'
        return self._u0_start

    def _centre(self) -> float:
        """The relay's centre u0 + μ0 (``autotune.relay_bias``, signed as the loop acts)."""
        return self._bias + self._direction() * self._cfg.relay_bias

    def _amplitude(self) -> float:
        """``autotune.relay_amplitude``, reduced so that ``u0 + μ0 ± d`` stays within the output
        limits (a clipped, asymmetric relay would defeat the bias correction and falsify the
        biased relay's equations)."""
        cfg, centre = self.pid.config, self._centre()
        room = 1.0 + self._cfg.additional_relay         # d·(1 + ρ) with the additional relay
        return min(self._cfg.relay_amplitude, (cfg.u_max - centre) / room,
                   (centre - cfg.u_min) / room)

    def _limit(self, u: float) -> float:
        """The PID's output limits and rate limit (du_max per second) applied to the relay output."""
        step = self.pid.rate_step                 # du_max·sample_time, None without a limit
        if self._last_out is not None and step is not None:
            u = min(max(u, self._last_out - step), self._last_out + step)
        return self._clip(u)

    def _direction(self) -> float:
        cfg = self.pid.config
        return -1.0 if (cfg.direct_action != (cfg.kp < 0)) else 1.0

    def _end(self, state: str, reason: str) -> None:
        """Leave the test: restore the gains from before it, PID resumes bumplessly from u0."""
        self._job = None                          # a result still being computed is dropped
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
        if self._state == 'step':
            return self._step_test(t, y, r)
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
            self._t_start = t
            self._y_rest = float(np.mean(wy))
            self._from_rest = steady
            self._drift = _trend(np.array(self._win_t), wy)
            if cfg.test == 'step':
                self._state = 'step'
                return self._step_test(t, y, r)
            self._state = 'relay'
            self._relay_high = r - y >= 0.0
            if self._amplitude() < 0.1 * self._cfg.relay_amplitude:
                self._end('failed', f'relay has no amplitude: the bias u0 = {self._u0:g} is within '
                                    f'10 % of autotune.relay_amplitude from an output limit')
                return None
            if abs(self._cfg.relay_bias) >= 0.9 * self._amplitude():
                self._end('failed', f'autotune.relay_bias {self._cfg.relay_bias:g} is not below '
                                    f'the relay amplitude the output limits leave '
                                    f'({self._amplitude():g}) by 10 %: no cycle would form')
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
        if self._integrating:
            return self._integrator_relay(t, y, sign)
        u = self._limit(self._centre() + self._direction() * (sign * self._amplitude()
                                                              + self._additional(sign)))
        switched = bool(self._rec_u) and (u != self._rec_u[-1])
        self._rec_t.append(t)
        self._rec_u.append(u)
        self._rec_y.append(y)
        if self._held is not None:
            if t - self._rec_t[0] >= self._held[1].record - 1e-9:
                self._finish_transient()
                if self._state not in TESTING:
                    return None
        elif self._job is not None:
            if t >= self._job.due - 1e-9 and (not self.wall_clock or self._job.done()):
                self._conclude(self._job.outcome())
                if self._state not in TESTING:
                    return None   # tuned (PID takes over from u0) or failed
        elif switched:
            self._analyse(t, r)
            if self._state not in TESTING:
                return None       # tuned (PID takes over from u0) or failed
        if t - self._t_start > cfg.timeout:
            what = 'no oscillation' if self._state == 'relay' else 'no stationary oscillation'
            self._end('failed', f'{what} within autotune.timeout = {cfg.timeout:g} s')
            return None
        return u

    def _analyse(self, t: float, r: float) -> bool:
        """At a relay switch: count cycles, correct the bias, identify and tune when enough are
        stationary (:meth:`_identify`, concluded at once or ``autotune.design_time`` s later)."""
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
        if (cfg.bias_correction and cfg.relay_bias == 0.0 and cfg.additional_relay == 0.0
                and len(asym) == 2
                and min(abs(a) for a in asym) > cfg.asymmetry_tol
                and asym[0] * asym[1] > 0.0):     # two cycles in a row, same side: not noise
            seg = slice(last.start, last.end)
            self._u0 = float(np.mean(np.array(self._rec_u)[seg]))
            self._first_cycle = last.end
            self._cycles = 0
            return False
        self._cycles = len(cycles)
        slack = 2.0 * self.sample_time
        extra = cfg.additional_relay > 0.0
        tail = (_stationary_pairs(cycles, cfg.min_cycles, cfg.stationarity_tol, slack) if extra
                else ident.stationary_cycles(cycles, cfg.min_cycles, cfg.stationarity_tol, slack))
        if tail is None:
            return False
        offload = cfg.design_time > 0.0 or self.wall_clock
        # to a process: a copy (pickled in the pool's feeder thread while this one samples on)
        work = copy.deepcopy(self)._identify if self.wall_clock else self._identify
        job = _Job(work, t + cfg.design_time,
                   (tt, uu, yy, self._bias_start, r, self._eps, tail, cfg), background=offload,
                   pool=_wall_pool() if self.wall_clock else None)
        if offload:
            self._job = job                       # the relay runs on until it is due
            return False
        self._conclude(job.outcome())
        return True

    def _identify(self, tt: np.ndarray, uu: np.ndarray, yy: np.ndarray, u0_start: float,
                  r: float, eps: float, tail: list[ident.RelayCycle], cfg: AutotuneConfig
                  ) -> _Outcome:
        """The identification from the relay record and the design from it: the heavy work,
        which reads no state a sample changes (a worker thread may run it)."""
        extra = cfg.additional_relay > 0.0
        sopdt = cfg.model == 'sopdt'
        try:
            res = ident.identify_relay(tt, uu, yy, u0_start, r, eps, cycles=tail,
                                       gain=cfg.process_gain or None,
                                       kind='auto' if sopdt else cfg.model)
            if extra:
                # [Precup2013] eqs. 3.3.19–3.3.21: over whole periods 2·Tc of u1 + u2 the harmonics of
                # π/Tc are the points 0.5·ωc, 1.5·ωc (those of 2π/Tc are ωc, 3ωc as before)
                w_half, g = ident.harmonic_response(tt, uu, yy, tail[0].start, tail[-1].end,
                                                    len(tail) // 2, (1, 3))
                res = replace(res, point_2=(w_half, g[1]))
                if sopdt:
                    model = ident.sopdt_from_two_points(2.0 * math.pi / res.tu,
                                                        complex(-1.0 / res.ku), w_half, g[1])
                    res = replace(res, model=model, model_method='two_points')
            elif sopdt:
                return _Outcome(res)              # the integrator phase follows
        except (ValueError, ArithmeticError) as exc:
            return _Outcome(error=f'identification/tuning failed: {exc}')
        try:
            return _Outcome(res, proposal=self._design(res, cfg))
        except (ValueError, ArithmeticError) as exc:
            return _Outcome(res, design_error=f'identification/tuning failed: {exc}')

    def _conclude(self, outcome: _Outcome) -> None:
        """The test's next step from :meth:`_identify`'s outcome (on the sampling path)."""
        self._job = None
        cfg = self._cfg
        if outcome.res is None:
            self._end('failed', outcome.error)
            return
        try:
            if cfg.model == 'sopdt' and cfg.additional_relay <= 0.0:
                self._begin_integrator(outcome.res)
                return
            if cfg.transient and self._hold_for_transient(outcome.res):
                return
        except (ValueError, ArithmeticError) as exc:
            self._end('failed', f'identification/tuning failed: {exc}')
            return
        if outcome.proposal is None:
            self._end('failed', outcome.design_error)
            return
        self._finish(outcome.res, outcome.proposal)

    def _hold_for_transient(self, res: ident.RelayIdentification) -> bool:
        """After the identification: keep the relay running until the record is long enough
        for the transient points (True), or say why there are none (False, ``warning``: not
        from rest, or a record longer than ``autotune.timeout``; the test tunes as usual)."""
        if not self._from_rest:
            self._transient_note = ('transient points skipped: the relay did not start from rest '
                                  '(the output was not steady within autotune.settle_band at '
                                  'autotune.settle_timeout)')
            return False
        slope, se = self._drift
        drift = abs(slope) * res.tu / res.amplitude
        if drift > TRANSIENT_MAX_DRIFT and abs(slope) > 6.0 * se:
            self._transient_note = (
                f'transient points skipped: the output still moved by {drift:.2g}·a per Tu when '
                f'the relay started (slope {slope:.3g}/s over autotune.settle_time; the points '
                f'need the loop at rest: at most {TRANSIENT_MAX_DRIFT:g}·a per Tu); start the '
                'test later or lengthen autotune.settle_time')
            return False
        try:
            plan = transient_plan(res.model, res.tu, self._cfg)
        except ValueError as exc:                 # a given α against the model's cut
            self._transient_note = f'transient points skipped: {exc}'
            return False
        if plan.record > self._cfg.timeout:
            self._transient_note = (
                f'transient points skipped: they need a relay record of {plan.record:.4g} s '
                f'(horizon {plan.horizon:.4g} s from the identified {res.model.kind} + 4/α) and '
                f'autotune.timeout is {self._cfg.timeout:g} s; set autotune.transient_horizon '
                'or a longer timeout')
            return False
        self._held = (res, plan)
        return True

    def _finish_transient(self) -> None:
        """The record is long enough: G(jω) at the transient points ([Precup2013] eqs. 3.3.1–3.3.10),
        then the design of the identification held since the stationary cycles."""
        assert self._held is not None
        res, plan = self._held
        self._held = None
        tt, yy = np.array(self._rec_t), np.array(self._rec_y)
        uu, _ = self._identification_input()
        omega = (2.0 * math.pi / res.tu) * np.array(self._cfg.transient_points)
        try:
            g = ident.transient_response(tt, uu, yy, self._bias_start, self._y_rest,
                                         np.append(omega, res.omega).tolist(), plan.alpha,
                                         plan.horizon,
                                         plan.smoothing, integrating=res.model.kind == 'ipdt')
            proposal = self._design(res, self._cfg)
        except (ValueError, ArithmeticError) as exc:
            self._end('failed', f'identification/tuning failed: {exc}')
            return
        # the cross-check: the same estimate at the oscillation frequency against the first
        # harmonic over the stationary cycles (accurate to < 1 % with 1 % noise)
        g, check = g[:-1], float(abs(g[-1] / res.g1 - 1.0))
        if check > TRANSIENT_CHECK_WARN:
            self._transient_note = (
                f'transient points: at the oscillation frequency {res.omega:.4g} rad/s they '
                f'differ from the first harmonic by {100 * check:.3g} % (noise, a start not '
                'at rest, or a cut before the pulse response died out: set '
                'autotune.transient_horizon)')
        lag = np.array([_model_lag(res.model, w) for w in omega])
        phase = np.angle(g) - 2.0 * np.pi * np.round((np.angle(g) + lag) / (2.0 * np.pi))
        self._finish(res, proposal, TransientPoints(omega, g, plan.alpha, plan.horizon,
                                                    float(tt[-1] - tt[0]), phase, check))

    def _step_test(self, t: float, y: float, r: float) -> float | None:
        """One sample of the open-loop step test ([DeadTimeNotes] §1.2.1): the input held at u0 + Δu; when
        the mean of the last window (a quarter of the time since the step, at least
        autotune.settle_time and 10 samples) differs from the window before by less than 0.5 %
        of the change since the step, the FOPDT is identified (for a first-order tail the change
        still to come is then below ≈ 0.8 %)."""
        cfg = self._cfg
        if cfg.max_amplitude > 0 and abs(y - r) > cfg.max_amplitude:
            self._end('failed', f'output deviation |y − r| = {abs(y - r):g} above '
                                f'autotune.max_amplitude = {cfg.max_amplitude:g}')
            return None
        u = self._limit(self._bias + self._direction() * cfg.step_size)
        self._rec_t.append(t)
        self._rec_u.append(u)
        self._rec_y.append(y)
        window = max(int(round(cfg.settle_time / self.sample_time)), 10, len(self._rec_y) // 4)
        if len(self._rec_y) >= 4 * window:
            last = float(np.mean(self._rec_y[-window:]))
            before = float(np.mean(self._rec_y[-2 * window:-window]))
            change = last - self._y_rest
            if abs(change) > max(cfg.settle_band, 10.0 * self._sigma) \
                    and abs(last - before) <= 0.005 * abs(change):
                self._identify_step()
                return None if self._state not in TESTING else u
        if t - self._t_start > cfg.timeout:
            self._end('failed', f'no steady step response within autotune.timeout = '
                                f'{cfg.timeout:g} s')
            return None
        return u

    def _identify_step(self) -> None:
        cfg = self._cfg
        tt = np.array(self._rec_t) - self._rec_t[0]
        step = float(self._rec_u[0] - self._bias)          # as applied (limits included)
        sign = self._direction()        # the step in the frame of a positive-gain plant
        try:
            model = ident.fopdt_from_step(tt, np.array(self._rec_y), self._y_rest, sign * step,
                                          cfg.step_method)
            res = ident.step_identification(model, step, cfg.step_method)
            proposal = self._design(res, cfg)
        except (ValueError, ArithmeticError) as exc:
            self._end('failed', f'identification/tuning failed: {exc}')
            return
        self._finish(res, proposal)

    def _additional(self, sign: float) -> float:
        """The additional relay's output u2 ([Precup2013] eq. 3.3.18): ρ·d at the start, negated at
        every upward switch of the relay (``sign`` −1 → +1); 0 when off."""
        rho = self._cfg.additional_relay
        if rho == 0.0:
            return 0.0
        if self._u2 is None:
            self._u2 = rho * self._amplitude()
        elif sign > 0.0 > self._last_sign:
            self._u2 = -self._u2
        self._last_sign = sign
        return self._u2

    def _begin_integrator(self, first: ident.RelayIdentification) -> None:
        """Second phase of ``autotune.model`` sopdt ([Precup2013] §3.3 intro): the relay drives an
        integrator, so the loop oscillates where arg G = −π/2. The integrator's rate makes the
        input a triangle of about ±d at the −90° frequency of the first phase's FOPDT (an IPDT
        has none: then at the period 3·Tu); it starts at the far side of the relay's direction,
        so the triangle is centred on u0."""
        w90 = (first.model.lag_frequency(0.5 * math.pi)
               if isinstance(first.model, ident.FopdtModel) else 2.0 * math.pi / (3.0 * first.tu))
        amp = self._amplitude()
        self._rate = 2.0 * amp * w90 / math.pi          # 4·d/P90 with P90 = 2π/ω90
        self._first, self._integrating = first, True
        sign = 1.0 if self._relay_high else -1.0
        self._u_int = self._bias - self._direction() * sign * amp
        for record in (self._rec_t, self._rec_u, self._rec_y, self._rec_s):
            record.clear()
        self._cycles = 0

    def _integrator_relay(self, t: float, y: float, sign: float) -> float | None:
        """One sample of the relay with an integrator in series (``sign``: the relay's state)."""
        self._u_int += self._direction() * sign * self._rate * self.sample_time
        u = self._limit(self._u_int)
        self._u_int = u                                  # no windup beyond the limits
        switched = bool(self._rec_s) and sign != self._rec_s[-1]
        self._rec_t.append(t)
        self._rec_u.append(u)
        self._rec_y.append(y)
        self._rec_s.append(sign)
        if switched:
            self._analyse_integrator()
            if self._state not in TESTING:
                return None
        if t - self._t_start > self._cfg.timeout:
            self._end('failed', f'no stationary oscillation with the integrator within '
                                f'autotune.timeout = {self._cfg.timeout:g} s')
            return None
        return u

    def _analyse_integrator(self) -> None:
        """At a switch of the integrator phase: when enough cycles are stationary, ``G(jω90)``
        by the first harmonic ([Precup2013] eqs. 3.3.19–3.3.21) and the SOPDT through it and the
        ultimate point ([Precup2013] eqs. 3.5.8–3.5.14)."""
        cfg, first = self._cfg, self._first
        tt, yy = np.array(self._rec_t), np.array(self._rec_y)
        cycles = ident.relay_cycles(tt, np.array(self._rec_s), yy, 0.0)[1:]
        if not cycles or cycles[-1].end != len(tt) - 1:
            return
        self._cycles = len(cycles)
        tail = ident.stationary_cycles(cycles, cfg.min_cycles, cfg.stationarity_tol,
                                       2.0 * self.sample_time)
        if tail is None or first is None:
            return
        uu, _ = self._identification_input()
        try:
            w90, g = ident.harmonic_response(tt, uu, yy, tail[0].start, tail[-1].end,
                                             len(tail), (1,))
            model = ident.sopdt_from_two_points(2.0 * math.pi / first.tu, complex(-1.0 / first.ku),
                                                w90, g[1])
            res = replace(first, model=model, model_method='two_points', point_2=(w90, g[1]))
            proposal = self._design(res, cfg)
        except (ValueError, ArithmeticError) as exc:
            self._end('failed', f'identification/tuning failed: {exc}')
            return
        self._finish(res, proposal)

    def _finish(self, res: ident.RelayIdentification, proposal: Proposal,
                transient: TransientPoints | None = None) -> None:
        """The test succeeded: keep the identification (and its transient points) and offer
        its design."""
        self._result, self._gains, self._transient = res, proposal.tuned, transient
        self._model, self._proposal = from_identified(res.model), proposal
        # The PID takes over from the bias u0, the equilibrium input, not from the last relay
        # value u0 ± d, which would disturb the loop by d.
        self._pending = self._u0
        self._state, self._reason = 'proposed', ''
        self._offer(proposal, after_test=True)
        if self._transient_note:
            self._warning = '; '.join(w for w in (self._warning, self._transient_note) if w)

    def _design(self, res: ident.RelayIdentification, cfg: AutotuneConfig) -> Proposal:
        """The proposal of ``cfg.rule`` from the identification ``res``: gains (the sign of the
        running kp kept: a reverse action by negative kp), margins and predicted response on
        the identified model, for the running PID's sample time, filter and limits."""
        gains = self._tune(res, cfg)
        sign = -1.0 if (self._saved_gains or _gain_fields(self.pid.config))['kp'] < 0 else 1.0
        kp, ti, td, b, c = (gains.get(name) for name in ('kp', 'ti', 'td', 'b', 'c'))
        if kp is None:
            raise ValueError(f'autotune: the rule {cfg.rule} gave no kp')
        new: dict[str, float] = {'kp': sign * abs(kp), 'ti': ti if ti else math.inf,
                                 'td': td if td else 0.0, 'b': b if b is not None else 1.0,
                                 'c': c if c is not None else 1.0}
        config = replace(self.pid.config, kp=new['kp'], ti=new['ti'], td=new['td'], b=new['b'],
                         c=new['c'])
        if config.reason():
            raise ValueError(config.reason())
        model = from_identified(res.model)
        return Proposal(new, dict(gains), loop_report(model, config), predict(model, config))

    def _offer(self, proposal: Proposal, after_test: bool = False) -> None:
        """A new proposal: applied at once with ``apply`` auto (unless refused), else pending
        (state ``proposed``)."""
        refusal = self.refusal(proposal)
        self._warning = f'proposal not applied: {refusal}' if refusal else ''
        if self._cfg.apply == 'auto' and not refusal:
            self.pid.set_gains(**proposal.gains)
            self._state = 'tuned' if after_test else 'running'
            self._arm_check()
        else:
            self._state = 'proposed'
            self._cancel_check()

    # ----------------------------------------------------------- verification
    def _arm_check(self) -> None:
        """After an apply: wait for the next setpoint change (or make the verification step)."""
        self._check = _Check(state='waiting', r_prev=self._check.r_prev,
                             window=self._verify_window())

    def _cancel_check(self, state: str = 'none') -> None:
        self._check = _Check(state=state, r_prev=self._check.r_prev)

    def _verify_window(self) -> float:
        if self._cfg.verify_window > 0:
            return self._cfg.verify_window
        settle = self._proposal.prediction.settling_time if self._proposal else math.nan
        tu = self._result.tu if self._result else 0.0
        if not math.isfinite(settle):
            settle = float(self._proposal.prediction.t[-1]) if self._proposal else 0.0
        return max(2.0 * settle, 4.0 * tu, 10.0 * self.sample_time)

    def _verify_sample(self, t: float, y: float, r: float) -> float:
        """The setpoint the PID uses this sample (the verification step added while it runs);
        detects the verified step, records it and compares it with its prediction."""
        c = self._check
        r_used = r + c.offset
        if c.state == 'waiting' and math.isfinite(y) and math.isfinite(r):
            step, cfg = self._cfg.verify_step, self._cfg
            noise = cfg.noise_band * self._sigma if math.isfinite(self._sigma) else 0.0
            band = max(0.02 * abs(step), noise)       # at rest: 2 % of the step, or the noise
            if abs(y - r) > band or c.r_prev != r:
                c.calm_since = None
            elif c.calm_since is None:
                c.calm_since = t
            if step == 0.0 and c.r_prev is not None and r != c.r_prev:
                self._begin_check(t, y, r, c.r_prev, r)
            elif (step != 0.0 and c.calm_since is not None
                  and t - c.calm_since >= cfg.settle_time - 1e-9):
                self._begin_check(t, y, r, r, r + step)      # the loop is at rest: step now
                c.offset, r_used = step, r + step
        elif c.state == 'measuring':
            if r != c.r_base or not math.isfinite(y):
                self._cancel_check('cancelled')
                r_used = r
            else:
                c.t.append(t)
                c.y.append(y)
                if t - c.t0 >= c.window - 1e-9:
                    self._finish_check()
                    r_used = r
        self._check.r_prev = r
        return r_used

    def _begin_check(self, t: float, y: float, r_base: float, r_old: float, r_new: float) -> None:
        """Start measuring a setpoint step r_old → r_new; its prediction is the same step
        simulated on the model from the operating point (output limits and rate limit of the
        running PID around the last output)."""
        c = self._check
        c.state, c.r_base, c.r_new, c.step = 'measuring', r_base, r_new, r_new - r_old
        c.t0, c.y0, c.t, c.y = t, y, [t], [y]
        cfg = self.pid.config
        u_op = self._last_out if self._last_out is not None else 0.0
        sign = -1.0 if cfg.direct_action != (cfg.kp < 0) else 1.0
        lo, hi = sorted((sign * (cfg.u_min - u_op), sign * (cfg.u_max - u_op)))
        sim = Pid2Dof(replace(cfg, kp=abs(cfg.kp), direct_action=False, u_min=lo, u_max=hi))
        sim.reset(0.0, 0.0, 0.0)
        assert self._model is not None             # a design follows an identification
        plant = DiscretePlant(self._model, self.sample_time)
        steps = int(round(c.window / self.sample_time)) + 1
        yp = np.empty(steps)
        for k in range(steps):
            yp[k] = plant.output()
            plant.step(sim.update(c.step, yp[k]))
        tp = self.sample_time * np.arange(steps)
        c.overshoot_predicted = float(step_metrics(tp, yp, c.step, y0=0.0).overshoot)
        c.iae_predicted = iae(tp, c.step - yp)

    def _finish_check(self) -> None:
        c = self._check
        t, y = np.array(c.t), np.array(c.y)
        c.overshoot_measured = float(step_metrics(t, y, c.r_new, y0=c.y0, t_step=c.t0).overshoot)
        c.iae_measured = iae(t, c.r_new - y)
        tol = self._cfg.verify_tolerance
        worse = (c.iae_measured > tol * c.iae_predicted
                 or c.overshoot_measured > tol * c.overshoot_predicted + 5.0)
        c.state, c.offset = ('worse' if worse else 'ok'), 0.0
        if worse:
            self._warning = (f'verification: the response is much worse than predicted: '
                             f'overshoot {c.overshoot_measured:.1f} % (predicted '
                             f'{c.overshoot_predicted:.1f} %), IAE {c.iae_measured:.4g} '
                             f'(predicted {c.iae_predicted:.4g}) over {c.window:g} s for a '
                             f'setpoint step of {c.step:g}')

    def _identification_input(self) -> tuple[np.ndarray, float]:
        """Recorded u as seen by a positive-gain plant and the current relay centre.

        Reverse-acting loops (negative plant gain) are mirrored around the initial bias.
        """
        uu = np.array(self._rec_u)
        if self._direction() < 0:
            return 2.0 * self._bias_start - uu, 2.0 * self._bias_start - self._bias
        return uu, self._bias

    def _tune(self, res: ident.RelayIdentification, cfg: AutotuneConfig
              ) -> dict[str, float | None]:
        from tank_control.core.tuning.rules import tune   # sibling package, imported when needed
        if cfg.rule in RULES_ULTIMATE:
            ku, tu = (res.ku, res.tu) if cfg.method == 'first_harmonic' else (res.ku_df, res.tu_df)
            return dict(tune(cfg.rule, cfg.kind, ku=ku, tu=tu))
        model = res.model
        if cfg.rule in RULES_IPDT:
            if not isinstance(model, ident.IpdtModel):
                raise ValueError(f'autotune.rule: {cfg.rule} needs an integrating (IPDT) model, '
                                 f'the relay data gave {model.kind}')
            return dict(tune(cfg.rule, cfg.kind, gain=model.gain, dead_time=model.dead_time))
        if cfg.rule in RULES_MODEL:
            return dict(tune(cfg.rule, cfg.kind, **design_arguments(
                from_identified(model), cfg, self.pid.config)))
        if not isinstance(model, ident.FopdtModel):
            raise ValueError(f'autotune.rule: {cfg.rule} needs an FOPDT model, the relay data gave '
                             f'{model.kind}')
        return dict(tune(cfg.rule, cfg.kind, gain=model.gain, time_constant=model.time_constant,
                         dead_time=model.dead_time))


def _stationary_pairs(cycles: list[ident.RelayCycle], count: int, tolerance: float,
                      slack: float) -> list[ident.RelayCycle] | None:
    """With the additional relay the relay's cycles alternate (u2 changes sign once per
    cycle): the last ``count`` cycles rounded up to whole pairs, if the pairs — one period of
    u1 + u2 each — are stationary (:func:`ident.stationary_cycles` on the pairs)."""
    pairs_needed = max(2, -(-count // 2))
    if len(cycles) < 2 * pairs_needed:
        return None
    tail = cycles[-2 * pairs_needed:]
    pairs = [ident.RelayCycle(a.start, b.end, a.period + b.period, a.high_time + b.high_time,
                              a.low_time + b.low_time, max(a.y_max, b.y_max),
                              min(a.y_min, b.y_min), 0.5 * (a.y1 + b.y1))
             for a, b in zip(tail[::2], tail[1::2])]
    return tail if ident.stationary_cycles(pairs, pairs_needed, tolerance, 2.0 * slack) else None


def _model_lag(model: ident.Model | ident.SopdtModel, omega: float) -> float:
    """Phase lag −arg G(jω) [rad] of an identified model, continuous in ω."""
    if isinstance(model, ident.SopdtModel):
        return omega * model.dead_time + math.atan2(model.b * omega, model.c - model.a * omega ** 2)
    if isinstance(model, ident.IpdtModel):
        return 0.5 * math.pi + omega * model.dead_time
    return model.order * math.atan(omega * model.time_constant) + omega * model.dead_time


def _trend(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope of ``y(t)`` [y units/s] and its standard error (0, 0 for fewer
    than 4 samples)."""
    if len(t) < 4:
        return 0.0, 0.0
    tc = t - t.mean()
    sxx = float(tc @ tc)
    if sxx <= 0.0:
        return 0.0, 0.0
    slope = float(tc @ (y - y.mean())) / sxx
    resid = y - y.mean() - slope * tc
    return slope, math.sqrt(float(resid @ resid) / (len(t) - 2) / sxx)


def design_arguments(model: ProcessModel, cfg: AutotuneConfig, pid: PidConfig) -> dict[str, Any]:
    """``tune`` arguments of a model-based rule: the model, the design targets of ``cfg``
    (0 = the rule's default) and the implemented loop (sample time, filter) of ``pid``."""
    args = {**model.tune_arguments(), 'sample_time': pid.sample_time, 'filter_n': pid.n}
    if cfg.rule == 'ms':
        args['ms'] = cfg.ms_target
    for name in ('tau_c', 'gain_margin', 'phase_margin'):
        if getattr(cfg, name):
            args[name] = getattr(cfg, name)
    return args


def _gain_fields(cfg: PidConfig) -> dict[str, Any]:
    return {'kp': cfg.kp, 'ti': cfg.ti, 'td': cfg.td, 'n': cfg.n, 'b': cfg.b, 'c': cfg.c}


_FLOAT64 = np.dtype(np.float64)


def _scalar(value: Any, name: str) -> float:
    if type(value) is np.ndarray and value.shape == (1,) and value.dtype is _FLOAT64:
        return value.item()
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != 1:
        raise ValueError(f'{name}: expected 1 value for the SISO relay auto-tuner, got {arr.size}')
    return float(arr[0])


@dataclass(frozen=True)
class _Outcome:
    """What :meth:`RelayAutotuner._identify` found: the identification ``res`` (None:
    ``error`` says why) and its ``proposal`` (None: ``design_error`` says why, or the
    integrator phase of an SOPDT test follows)."""

    res: ident.RelayIdentification | None = None
    proposal: Proposal | None = None
    error: str = ''
    design_error: str = ''


_WORKER: ThreadPoolExecutor | None = None
_WORKER_LOCK = threading.Lock()


def _worker() -> ThreadPoolExecutor:
    """One thread for the auto-tuners' heavy work (numpy/scipy release the GIL in their
    kernels; the sampling thread keeps its instants)."""
    global _WORKER
    with _WORKER_LOCK:
        if _WORKER is None:
            _WORKER = ThreadPoolExecutor(max_workers=1, thread_name_prefix='autotune')
        return _WORKER


_PROCESS: ProcessPoolExecutor | None = None


def _wall_pool() -> Executor:
    """Wall mode: one spawned process (started with the first test). The fit and the Ms search
    are Python loops as much as numpy: in a thread they hold the GIL for most of a second, and
    the sampling thread, waking for its instant, waits for it — on a loaded machine long enough
    to come late (bench/bench_live_rebuild.py); a process shares no GIL."""
    global _PROCESS
    with _WORKER_LOCK:
        if _PROCESS is None:
            _PROCESS = ProcessPoolExecutor(max_workers=1,
                                           mp_context=multiprocessing.get_context('spawn'))
        return _PROCESS


def _warm() -> None:
    """Imports the identification in the wall-mode process before a test needs it."""


class _Job:
    """``work(*args)`` computed in the worker thread (``background``) or when first asked for;
    its outcome is taken at the first sample at or after ``due`` [s]. A copy of a tuner (a
    live change's trial) shares the job: its outcome does not depend on who asks."""

    def __init__(self, work: Any, due: float, args: tuple[Any, ...], background: bool,
                 pool: Executor | None = None) -> None:
        self.due = due
        self._work, self._args = work, args
        self._future: Future[Any] | None = (
            (pool or _worker()).submit(work, *args) if background else None)

    def done(self) -> bool:
        """The outcome is there (taking it does not wait)."""
        return self._future is None or self._future.done()

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the outcome is there (at most ``timeout`` s); ``done()``."""
        if self._future is not None:
            futures_wait([self._future], timeout)
        return self.done()

    def outcome(self) -> Any:
        if self._future is None:
            return self._work(*self._args)
        return self._future.result()     # waits only if the work is not done by its sample

    def __deepcopy__(self, memo: dict[int, Any]) -> _Job:
        return self
