"""Discrete lead-lag compensator and [Ikonen]'s frequency-domain design of it ([Ikonen] §1.1–1.4, [Checks] §2).

Continuous law ([Ikonen] §1.2 lead "PD", §1.3 PI, §1.4 series PID)::

    C(s) = kp · (td·s + 1)/(alpha·td·s + 1) · (1 + 1/(ti·s)),   E = W − Y

The lead (0 < alpha < 1, ``td = 0``: none) has its largest phase lead
``asin((1 − alpha)/(1 + alpha))`` at ``w_max = 1/(td·√alpha)`` [rad/s] and the gain 1 at low,
``1/alpha`` at high frequency; the PI (the lag part, ``ti = inf``: none) removes the steady-state
error. Units: ``kp`` in u units per y unit, ``td``, ``ti``, ``sample_time`` in s, phases in
degrees at the API.

Discretisation (sample time ``h``):

* lead: matched pole-zero, its zero ``−1/td`` and pole ``−1/(alpha·td)`` mapped by
  ``z = e^(s·h)``, the gain matched at ``z = 1``::

      L(z) = g·(z − z0)/(z − p0) = 1 + gd·(z − 1)/(z − p0),
      z0 = e^(−h/td), p0 = e^(−h/(alpha·td)), g = (1 − p0)/(1 − z0), gd = g − 1

  Its pole ``p0`` lies in (0, 1) for every ``h``: stable and free of ringing (Tustin rings
  once ``h > 2·alpha·td``); ``L(1) = 1`` exactly; it tends to the continuous network as
  ``h → 0`` (``gd → (1 − alpha)/alpha``). At the crossover it keeps the lead's phase to within
  a small part of the hold's half sample, where the backward difference (the PID's derivative
  filter) would cost about another ``ω·h/2``. Realised as ``e_f = e + gd·(e − x)`` with the
  low-pass state ``x ← p0·x + (1 − p0)·e`` updated after.
* PI after the lead, forward Euler in output units: ``v = kp·e_f + I``,
  ``I ← I + kp·h/ti·e_f`` (so ``ti`` changes are bumpless), i.e. ``1 + h/(ti·(z − 1))``.

So the implemented law is exactly (:func:`discrete_polynomials`, :func:`discrete_response`)::

    C(z) = kp · (1 + h/(ti·(z − 1))) · g·(z − z0)/(z − p0)

Behaviour users rely on (as the PID's): output limits ``[u_min, u_max]``; anti-windup of the
integral (``back_calculation`` with tracking time ``Tt``, default ``ti``, ``h/Tt`` capped at 1;
``conditional_integration``; ``none``); no kick on the first sample or after ``reset`` (the
lead starts at the steady state of the current error); ``reset(r, y, u)`` makes the next
output ``u``; bumpless gain changes (the integral, or without integral action the output bias
``I``, absorbs them); manual/auto bumpless both ways; a non-finite ``r`` or ``y`` holds the
last output and leaves the state untouched; ``direct_action`` reverses the sign.

Design (:func:`design`, [Ikonen]; the procedure is ``core/tuning/design_002.py``): P for the
steady-state error ``1/(1 + kp·K) <= e`` (§1.1); PD: the lead's ``w_max`` at the P loop's gain
crossover, moved to the mean of itself and the new crossover until the phase margin reaches
its target (§1.2; no lead if the P loop has it); PI: the gain and ``ti = ratio/w_c`` (the
integral corner a decade below the P loop's crossover) that give the target phase margin
(§1.3); series PID: the PD's ``td``, the PI's ``ti``, the mean of the two gains (§1.4). The
design is continuous (exact dead time, margins from ``core/analysis/frequency.py``); the
sampled loop loses about ``w_c·h/2`` of phase to the hold.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tank_control.core.analysis import frequency as fr
from tank_control.core.control.pid import (BIG, anti_windup_param, limits_reason,
                                           sample_time_param)
from tank_control.core.control.siso_law import SisoController, SisoLaw
from tank_control.core.params import TIME_TINY, ConfigError, check_config, param
from tank_control.core.tuning import design_002
from tank_control.core.tuning.design_002 import Design, LeadStep  # noqa: F401 (re-exported)
from tank_control.core.tuning.model import ProcessModel

ALPHA_MIN, ALPHA_MAX = 0.01, 0.99


# ============================================================================ the law
@dataclass
class LeadLagConfig:
    """Settings of :class:`LeadLag` ([Ikonen] §1.2–1.4); every field is a parameter.

    As parameters ``lead_lag.ti = 0`` means no integral action (``inf``) and
    ``tracking_time = 0`` the default ``Tt = ti``."""

    kp: float = param(1.0, 'gain K of C(s) = K (Td s + 1)/(alpha Td s + 1) (1 + 1/(Ti s)); > 0, '
                      'use direct_action for the opposite sign', unit='u units per y unit',
                      min=0.0, max=BIG, name='lead_lag.kp', source='[Ikonen] §1.4')
    td: float = param(0.0, 'lead time Td: largest phase lead at w_max = 1/(Td sqrt(alpha)) '
                      '(0 = no lead)', unit='s', min=0.0, max=BIG, tiny=TIME_TINY,
                      name='lead_lag.td', source='[Ikonen] §1.2')
    alpha: float = param(0.1, 'lead pole/zero ratio alpha = Tf/Td; largest lead '
                         'asin((1 - alpha)/(1 + alpha)), high-frequency gain K/alpha', unit='-',
                         min=ALPHA_MIN, max=ALPHA_MAX, name='lead_lag.alpha', source='[Ikonen] §1.2')
    ti: float = param(math.inf, 'integral time Ti of the series PI (0 = no integral action)',
                      unit='s', min=0.0, max=BIG, tiny=TIME_TINY, zero=math.inf,
                      name='lead_lag.ti', source='[Ikonen] §1.3')
    sample_time: float = sample_time_param()
    u_min: float = param(-1e9, 'lower output limit', unit='u units', min=-BIG, max=BIG)
    u_max: float = param(1e9, 'upper output limit', unit='u units', min=-BIG, max=BIG)
    anti_windup: str = anti_windup_param()
    tracking_time: float | None = param(None, 'back-calculation tracking time Tt (0 = default '
                                        'Ti)', unit='s', min=0.0, max=BIG, tiny=TIME_TINY,
                                        zero=None)
    direct_action: bool = param(False, 'true: output rises when the measurement rises')

    def reason(self) -> str | None:
        """Relations between the fields (one line naming the parameter), or None."""
        if not self.kp > 0.0:
            return f'lead_lag.kp: {self.kp!r} must be > 0 (direct_action reverses the sign)'
        if not self.ti > 0.0:
            return f'lead_lag.ti: {self.ti!r} is out of range; allowed (0, inf] s (0 = none)'
        return limits_reason(self.u_min, self.u_max, self.anti_windup)


def lead_constants(td: float, alpha: float, h: float) -> tuple[float, float]:
    """``(p0, gd)`` of the matched pole-zero lead: pole ``p0 = e^(−h/(alpha·td))`` and
    ``gd = (z0 − p0)/(1 − z0)``, ``z0 = e^(−h/td)``; ``(0, 0)`` without a lead (``td = 0``)."""
    if td <= 0.0:
        return 0.0, 0.0
    pole_time = alpha * td               # may underflow to 0 for a tiny td: no lead pole
    a, b = -h / td, (-h / pole_time if pole_time > 0.0 else -math.inf)
    return math.exp(b), (math.expm1(a) - math.expm1(b)) / -math.expm1(a)


class LeadLag(SisoLaw[LeadLagConfig]):
    """Discrete lead-lag compensator ([Ikonen] §1.2–1.4); see the module docstring.

    ``update(r, y)`` once per sample (every ``sample_time`` seconds) returns the output.
    Modes, limits, faults and the integral: :class:`SisoLaw`."""

    unknown_setting = 'unknown lead-lag setting'

    def __init__(self, config: LeadLagConfig) -> None:
        super().__init__(config)
        self._e_f = 0.0         # lead output (filtered error) [units of e = r − y]

    def _check(self, config: LeadLagConfig) -> None:
        check_config(config)

    def _terms(self) -> dict[str, float]:
        """The lead's output ``lead`` (filtered error) and the integral ``i``."""
        return {'lead': self._e_f, 'i': self._i_out}

    def _default_tracking_time(self) -> float:
        return self._cfg.ti

    def _next_v(self, cfg: LeadLagConfig, e: float) -> float:
        """The output before limits of the next sample at error ``e`` from the current state."""
        gd = lead_constants(cfg.td, cfg.alpha, cfg.sample_time)[1]
        return self._gain(cfg) * (e + gd * (e - self._x)) + self._i

    def _rest(self, r: float, y: float) -> float:
        """The lead at rest at ``e = r − y`` (no kick); returns ``kp·e``."""
        e = r - y
        self._x = e
        self._e_f = e
        return self._gain() * e

    def _update_auto(self, r: float, y: float) -> float:
        cfg = self._cfg
        k, h, e = self._gain(), cfg.sample_time, r - y
        if cfg.td > 0.0:
            p0, gd = lead_constants(cfg.td, cfg.alpha, h)
            e_f = e + gd * (e - self._x)
            x_next = p0 * self._x + (1.0 - p0) * e
        else:
            x_next, e_f = e, e
        v = k * e_f + self._i
        if not self._accept(v, x_next):
            return self._hold_output()
        self._e_f = e_f
        return self._apply(r, y, v, k, e_f)

    def _retune(self, old: LeadLagConfig, new: LeadLagConfig, r: float, y: float) -> None:
        """The integral absorbs the change of the next output at the last error (not during
        an input fault: the recovery re-tracks)."""
        if not self._fault:
            e = r - y
            self._i += self._next_v(old, e) - self._next_v(new, e)


class LeadLagController(SisoController[LeadLag]):
    """:class:`LeadLag` behind the Controller protocol (SISO): reads ``output_name`` and its
    setpoint, writes ``input_name``. ``reset(y, u)`` is completed at the next ``step`` (which
    knows ``r``) and that step returns ``u``."""

    law_name = 'lead-lag'

    def __init__(self, config: LeadLagConfig, output_name: str = 'y',
                 input_name: str = 'u') -> None:
        super().__init__(LeadLag(config), output_name, input_name)

    @property
    def lead_lag(self) -> LeadLag:
        return self._law


# ===================================================================== transfer functions
def discrete_polynomials(kp: float, td: float, alpha: float, ti: float,
                         sample_time: float) -> tuple[np.ndarray, np.ndarray]:
    """``(num, den)`` in z, highest power first, of the implemented ``C(z) = −U/Y = U/W``:
    ``kp·(ti·z − ti + h)/(ti·(z − 1)) · g·(z − z0)/(z − p0)`` with ``z0 = e^(−h/td)``,
    ``p0 = e^(−h/(alpha·td))``, ``g = (1 − p0)/(1 − z0)`` (lead: matched pole-zero; PI:
    forward Euler; ``ti = inf``/``td = 0``: that part is 1)."""
    h = sample_time
    num, den = np.array([float(kp)]), np.array([1.0])
    if td > 0.0:
        z0, p0 = math.exp(-h / td), math.exp(-h / (alpha * td))
        g = math.expm1(-h / (alpha * td)) / math.expm1(-h / td)      # (1 − p0)/(1 − z0)
        num = np.convolve(num, [g, -g * z0])
        den = np.convolve(den, [1.0, -p0])
    if math.isfinite(ti):
        num = np.convolve(num, [ti, h - ti])
        den = np.convolve(den, [ti, -ti])
    return num, den


def discrete_response(kp: float, td: float, alpha: float, ti: float,
                      sample_time: float) -> fr.FrequencyResponse:
    """Frequency response ``C(e^(jωh))`` of the implemented law (:func:`discrete_polynomials`)."""
    num, den = discrete_polynomials(kp, td, alpha, ti, sample_time)
    with np.errstate(invalid='ignore'):   # the PI's zero 1 − h/ti < 0 (h > ti): no corner
        return fr.rational_discrete(num, den, sample_time)


def continuous_response(kp: float, td: float, alpha: float,
                        ti: float = math.inf) -> fr.FrequencyResponse:
    """``C(s) = kp·(td·s + 1)/(alpha·td·s + 1)·(1 + 1/(ti·s))`` ([Ikonen] §1.4;
    :func:`design_002.controller_response`)."""
    return design_002.controller_response(kp, td, alpha, ti)


# ================================================================================ design
MODELS = ('fopdt', 'sopdt', 'ipdt')
STRUCTURES = ('p', 'pd', 'pi', 'pid')
RULES = ('none', 'frequency_002')


@dataclass(frozen=True)
class LeadLagTuning:
    """The design group: a rule, the structure it designs, the process model and the targets."""

    rule: str = param('none', "design rule; frequency_002: lead_lag.kp, lead_lag.td, lead_lag.ti "
                      "come from [Ikonen]'s frequency-domain design on the model tuning.model",
                      name='tuning.rule', choices=RULES, source='[Ikonen] §1')
    kind: str = param('pid', 'structure designed: p (gain for the steady-state error), pd (lead '
                      'at the crossover), pi (gain and Ti for the phase margin), pid (series '
                      'PD times PI, the mean gain)', name='tuning.kind', choices=STRUCTURES)
    model: str = param('fopdt', 'process model: fopdt K/(T s+1) e^(-L s), sopdt '
                       'K/((T s+1)(T2 s+1)) e^(-L s), ipdt K/s e^(-L s)', name='tuning.model',
                       choices=MODELS)
    gain: float = param(0.0, 'process gain K (0 = not given)',
                        unit='y units per u unit, per s for ipdt', min=0.0, max=BIG,
                        name='tuning.gain')
    time_constant: float = param(0.0, 'process time constant T (fopdt, sopdt)', unit='s',
                                 min=0.0, max=BIG, tiny=TIME_TINY, name='tuning.time_constant')
    time_constant2: float = param(0.0, 'second time constant T2 (sopdt)', unit='s', min=0.0,
                                  max=BIG, tiny=TIME_TINY, name='tuning.time_constant2')
    dead_time: float = param(0.0, 'process dead time L', unit='s', min=0.0, max=BIG, tiny=TIME_TINY,
                             name='tuning.dead_time')
    phase_margin: float = param(60.0, 'target phase margin ([Ikonen]: 5 % overshoot, damping 0.6, '
                                '60 deg)', unit='deg', min=1.0, max=89.0,
                                name='tuning.phase_margin', source='[Ikonen] §1.2')
    steady_state_error: float = param(0.05, 'largest steady-state error after a setpoint step, '
                                      'a fraction of the step (sets the gain of p, pd and the '
                                      'PD part of pid)', unit='-', min=0.001, max=0.4,
                                      name='tuning.steady_state_error', source='[Ikonen] §1.1')
    integral_ratio: float = param(10.0, 'integral corner 1/Ti this many times below the P '
                                  "loop's crossover ([Ikonen]: a decade)", unit='-', min=2.0,
                                  max=1000.0, name='tuning.integral_ratio', source='[Ikonen] §1.3')

    def reason(self) -> str | None:
        """The model's parameters a rule needs, and none it does not use (one line)."""
        if self.rule == 'none':
            return None
        needs = {'fopdt': ('time_constant',), 'sopdt': ('time_constant', 'time_constant2'),
                 'ipdt': ()}[self.model]
        if not self.gain > 0.0:
            return (f'tuning.gain: needed by tuning.rule {self.rule!r}; allowed (0, {BIG:g}] '
                    '(a reverse-acting process: its magnitude and direct_action true)')
        for name in needs:
            if not getattr(self, name) > 0.0:
                return (f'tuning.{name}: needed by tuning.model {self.model!r}; allowed '
                        f'(0, {BIG:g}] s')
        for name in ('time_constant', 'time_constant2'):
            if name not in needs and getattr(self, name) != 0.0:
                return (f'tuning.{name}: {getattr(self, name):g} is not used by tuning.model '
                        f'{self.model!r}; allowed 0')
        return None

    def process(self) -> ProcessModel:
        """The model ([Ikonen]'s 4/((s+1)(s+2)) is ``sopdt`` K 2, T 1 s, T2 0.5 s; FOPDT [DeadTimeNotes] eq.
        6.14; IPDT [Viteckova] eq. 1) with its closed-form magnitude and phase."""
        return ProcessModel(self.model, self.gain, self.dead_time, self.time_constant,
                            self.time_constant2)


def design(tuning: LeadLagTuning, alpha: float) -> Design:
    """[Ikonen]'s design of ``tuning.kind`` for ``tuning.process()`` with the lead ratio ``alpha``
    (:func:`tank_control.core.tuning.design_002.design`). Raises :class:`ConfigError` (one
    line naming the parameter) when the target is out of reach or the rule does not apply."""
    if tuning.rule == 'none':
        raise ConfigError("tuning.rule: 'none' designs nothing; allowed frequency_002")
    reason = tuning.reason()
    if reason:
        raise ConfigError(reason)
    return design_002.design(tuning.process(), tuning.kind, tuning.steady_state_error,
                             tuning.phase_margin, tuning.integral_ratio, alpha)
