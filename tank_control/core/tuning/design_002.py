"""[Ikonen]'s frequency-domain PID design (E. Ikonen, Univ. of Oulu; [Checks] §2, [Checks] §5).

The document designs, on its process ``G(s) = 4/((s + 1)(s + 2))``, for a steady-state error
of at most 5 % and an overshoot of at most 5 %:

* **§1.1 P** — a setpoint step leaves the error ``e = 1/(1 + kp·G(0))`` ([Ikonen] §1.1), so
  ``kp = (1/e − 1)/G(0)`` (:func:`p_gain`; 9.5 for 5 % and ``G(0) = 2``). Its loop has
  28.1° at 5.96 rad/s ([Ikonen] Fig. 2) and overshoots by more than 40 % (Fig. 1).
* **§1.2 the overshoot target as a phase margin** — damping ``ζ ≈ PM/100`` (PM in degrees)
  and the second-order overshoot ``Mp = exp(−π·ζ/√(1 − ζ²))``: 5 % → ζ ≈ 0.6 → PM ≈ 60°
  (:func:`damping_from_phase_margin`, :func:`overshoot_from_damping`,
  :func:`phase_margin_for_overshoot`).
* **§1.2 lead ("PD")** ``C(s) = kp·(Td·s + 1)/(α·Td·s + 1)`` (α = Tf/Td = 0.1): the largest
  phase lead ``asin((1 − α)/(1 + α))`` (:func:`lead_max_phase`) sits at
  ``ω_max = 1/(Td·√α)`` (:func:`lead_time`). Put ω_max at the P loop's crossover; the lead
  raises the gain there, so the crossover moves up; put ω_max at the mean of the previous
  ω_max and the new crossover and repeat until the phase margin reaches the target
  (:func:`lead_iteration`; [Ikonen]: 6 rad/s → 54.9° at 15.5 rad/s, then 10.8 rad/s → 70.5°).
* **§1.3 PI** ``kp·(1 + 1/(Ti·s))``: lower the gain until the loop has the phase margin,
  then put the integral corner a decade below the crossover, ``Ti = 10/ω_c``
  (:func:`integral_time`; [Ikonen]: kp 2, 62.9° at 2.37 rad/s, Ti = 10/2.4 = 4.2 s, 57.1°).
  :func:`design_pi` solves for the gain at which the PI loop (corner included) has exactly
  the target; [Ikonen] picked kp = 2 by eye (the target 57.07° gives back kp 2.00, Ti 4.21 s).
* **§1.4 series PID** = PD·PI with the mean of the two gains (:func:`design_pid`; [Ikonen]:
  5.75·(0.29·s + 1)/(0.029·s + 1)·(1 + 1/(4.2·s)), 75° at 7 rad/s).

The design is continuous; margins, crossovers and the Nyquist stability check are the
project's exact-delay frequency analysis (``core/analysis/frequency.py``: :func:`fr.margins`,
:func:`fr.closed_loop_stable`), so any continuous process it describes can be designed for:
``fr.rational(num, den, dead_time)`` (the ``transfer_function`` plant), ``fr.fopdt``,
``fr.ipdt`` or a :class:`~tank_control.core.tuning.model.ProcessModel`. Units: gains in input
units per output unit, times in s, frequencies in rad/s, phases in degrees, errors and
overshoots as fractions of the step. Refusals raise :class:`ConfigError` whose one-line
message names the ``tuning.*`` / ``lead_lag.alpha`` parameter of the ``lead_lag`` controller
kind that corresponds to the argument (the kind designs with :func:`design`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from tank_control.core.scipy_lazy import brentq

from tank_control.core.analysis import frequency as fr
from tank_control.core.params import ConfigError

ALPHA_002 = 0.1
"""[Ikonen]'s lead ratio α = Tf/Td ("the derivative filter ten times faster")."""
KINDS = ('p', 'pd', 'pi', 'pid')
MAX_LEAD_STEPS = 60


# ====================================================== phase margin, damping, overshoot
def damping_from_phase_margin(phase_margin: float) -> float:
    """[Ikonen] §1.2 rule of thumb: damping ``ζ ≈ PM/100`` (``phase_margin`` in degrees)."""
    return phase_margin / 100.0


def phase_margin_from_damping(zeta: float) -> float:
    """The inverse of :func:`damping_from_phase_margin`: ``PM ≈ 100·ζ`` [deg]."""
    return 100.0 * zeta


def overshoot_from_damping(zeta: float) -> float:
    """[Ikonen] §1.2: step overshoot ``Mp = exp(−π·ζ/√(1 − ζ²))`` of the second-order system
    ``ω_n²/(s² + 2ζω_n·s + ω_n²)`` (a fraction; 0 for ``ζ ≥ 1``)."""
    if not 0.0 <= zeta:
        raise ValueError(f'zeta: {zeta!r} must be >= 0')
    if zeta >= 1.0:
        return 0.0
    return math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta * zeta))


def damping_from_overshoot(overshoot: float) -> float:
    """The inverse of :func:`overshoot_from_damping`: ``ζ = −ln Mp/√(π² + ln² Mp)``
    (``overshoot`` a fraction in (0, 1))."""
    if not 0.0 < overshoot < 1.0:
        raise ValueError(f'overshoot: {overshoot!r} must be in (0, 1)')
    log = math.log(overshoot)
    return -log / math.sqrt(math.pi ** 2 + log ** 2)


def phase_margin_for_overshoot(overshoot: float) -> float:
    """[Ikonen] §1.2's chain: the phase margin [deg] for the step overshoot ``overshoot`` (a
    fraction), ``100·ζ`` with ζ from :func:`damping_from_overshoot` (5 % → 69.0°; the
    document rounds ζ to 0.6 and works with 60°, which by the same formulas is 9.5 %)."""
    return phase_margin_from_damping(damping_from_overshoot(overshoot))


def exact_phase_margin(zeta: float) -> float:
    """Not in [Ikonen] (a check of its rule): the exact phase margin [deg] of the loop
    ``ω_n²/(s·(s + 2ζω_n))`` whose closed loop is the second-order system of damping ζ,
    ``atan(2ζ/√(√(1 + 4ζ⁴) − 2ζ²))`` (0.6 → 59.2°, 0.69 → 64.6°)."""
    return math.degrees(math.atan(2 * zeta / math.sqrt(math.sqrt(1 + 4 * zeta ** 4)
                                                       - 2 * zeta ** 2)))


# ========================================================================= the pieces
def steady_state_error(kp: float, static_gain: float) -> float:
    """[Ikonen] §1.1: the error left by a setpoint step under P control, ``1/(1 + kp·G(0))`` (a
    fraction of the step; 0 for an integrating process, ``static_gain`` inf)."""
    return 0.0 if math.isinf(static_gain) else 1.0 / (1.0 + kp * static_gain)


def p_gain(static_gain: float, error: float) -> float:
    """[Ikonen] §1.1: the P gain that leaves the steady-state error ``error`` (a fraction),
    ``kp = (1/e − 1)/G(0)`` (9.5 for 5 % and G(0) = 2). An integrating process
    (``static_gain`` inf) has no such gain: ``ConfigError``."""
    if math.isinf(static_gain):
        raise ConfigError('tuning.kind: the gain comes from the steady-state error ([Ikonen] §1.1), '
                          'and an integrating process (tuning.model ipdt) has none at any '
                          'gain; allowed pi')
    if not 0.0 < error < 1.0:
        raise ConfigError(f'tuning.steady_state_error: {error!r} must be in (0, 1)')
    if not static_gain > 0.0:
        raise ConfigError(f'tuning.gain: the static gain {static_gain!r} must be > 0 (a '
                          'reverse-acting process: its magnitude and direct_action true)')
    return (1.0 / error - 1.0) / static_gain


def lead_max_phase(alpha: float) -> float:
    """[Ikonen] §1.2: the largest phase lead [deg] of ``(Td·s + 1)/(α·Td·s + 1)``,
    ``asin((1 − α)/(1 + α))`` (54.9° for α = 0.1)."""
    return math.degrees(math.asin((1.0 - alpha) / (1.0 + alpha)))


def lead_time(w_max: float, alpha: float) -> float:
    """[Ikonen] §1.2: the lead time ``Td = 1/(ω_max·√α)`` [s] that puts the largest phase lead at
    ``w_max`` [rad/s] ([Ikonen]: 1/(6·√0.1) = 0.53 s, 1/(10.8·√0.1) = 0.29 s)."""
    return 1.0 / (w_max * math.sqrt(alpha))


def lead_w_max(td: float, alpha: float) -> float:
    """The inverse of :func:`lead_time`: ``ω_max = 1/(Td·√α)`` [rad/s]."""
    return 1.0 / (td * math.sqrt(alpha))


def integral_time(wc: float, ratio: float = 10.0) -> float:
    """[Ikonen] §1.3: the integral corner ``1/Ti`` a decade (``ratio``) below the crossover ``wc``
    [rad/s]: ``Ti = ratio/wc`` [s] ([Ikonen]: 10/2.4 = 4.2 s)."""
    return ratio / wc


def controller_response(kp: float, td: float = 0.0, alpha: float = ALPHA_002,
                        ti: float = math.inf) -> fr.FrequencyResponse:
    """``C(s) = kp·(td·s + 1)/(alpha·td·s + 1)·(1 + 1/(ti·s))`` ([Ikonen] §1.4; ``td = 0``: no
    lead, ``ti = inf``: no integral action)."""
    num, den = np.array([float(kp)]), np.array([1.0])
    if td > 0.0:
        num, den = np.convolve(num, [td, 1.0]), np.convolve(den, [alpha * td, 1.0])
    if math.isfinite(ti):
        num, den = np.convolve(num, [ti, 1.0]), np.convolve(den, [ti, 0.0])
    return fr.rational(num, den)


def process_response(process: Any) -> fr.FrequencyResponse:
    """A continuous :class:`fr.FrequencyResponse` as is, or a ``ProcessModel``'s
    (:meth:`ProcessModel.response`)."""
    g = process if isinstance(process, fr.FrequencyResponse) else process.response()
    if g.discrete:
        raise ValueError('process: [Ikonen] designs on the continuous process; give its continuous '
                         'response (sample_time 0)')
    return g


def static_gain(process: Any) -> float:
    """``G(0)`` of the continuous process (inf with an integrator)."""
    g = process_response(process)
    if g.integrators > 0:
        return math.inf
    return float(complex(g.rational(np.asarray([0j]))[0]).real)


def loop_margins(process: Any, kp: float, td: float = 0.0, alpha: float = ALPHA_002,
                 ti: float = math.inf) -> fr.Margins:
    """:func:`fr.margins` of the loop ``C(s)·G(s)`` (:func:`controller_response`; the phase
    margin is the worst over the gain crossovers, exact dead time)."""
    return fr.margins(controller_response(kp, td, alpha, ti) * process_response(process))


def loop_stable(process: Any, kp: float, td: float = 0.0, alpha: float = ALPHA_002,
                ti: float = math.inf) -> bool:
    """Nyquist count of the closed loop with the exact dead time
    (:func:`fr.closed_loop_stable`)."""
    return fr.closed_loop_stable(controller_response(kp, td, alpha, ti)
                                 * process_response(process))


# ============================================================================ designs
@dataclass(frozen=True)
class LeadStep:
    """One step of [Ikonen]'s lead iteration: ``w_max`` [rad/s], ``td`` [s] and the resulting
    loop's ``phase_margin`` [deg] at its crossover ``wc`` [rad/s]."""

    w_max: float
    td: float
    phase_margin: float
    wc: float


@dataclass(frozen=True)
class Design:
    """The designed ``kp``, ``td`` (0 = no lead), ``ti`` (inf = none) and the loop's
    ``phase_margin`` [deg] at ``wc`` [rad/s]; the steps: the P gain for the steady-state
    error and its loop (``p_*``), the lead iteration (``lead_steps``), the PI gain and the
    crossover of its P loop (``pi_*``)."""

    kp: float
    td: float
    ti: float
    phase_margin: float
    wc: float
    p_gain: float = math.nan
    p_phase_margin: float = math.nan
    p_wc: float = math.nan
    lead_steps: tuple[LeadStep, ...] = field(default=())
    pi_gain: float = math.nan
    pi_wc: float = math.nan

    def values(self) -> dict[str, float]:
        """As parameter values of the ``lead_lag`` kind (``lead_lag.ti`` 0 = none)."""
        return {'lead_lag.kp': self.kp, 'lead_lag.td': self.td,
                'lead_lag.ti': self.ti if math.isfinite(self.ti) else 0.0}


def _margin(m: fr.Margins) -> tuple[float, float]:
    """``(phase margin, crossover)``; ``(inf, nan)`` when |L| never crosses 1."""
    return (m.phase_margin, m.wc) if math.isfinite(m.phase_margin) else (math.inf, math.nan)


def design_p(process: Any, error: float = 0.05, alpha: float = ALPHA_002,
             check: bool = True) -> Design:
    """[Ikonen] §1.1: the gain for the steady-state error ``error`` (:func:`p_gain`) and its
    loop's margin (``check``: refused if that loop is unstable)."""
    kp = p_gain(static_gain(process), error)
    pm, wc = _margin(loop_margins(process, kp))
    if check and not loop_stable(process, kp):
        raise ConfigError(f'tuning.steady_state_error: {error:g} needs the gain {kp:.6g}, '
                          'which makes the loop unstable; allow a larger error')
    return Design(kp, 0.0, math.inf, pm, wc, kp, pm, wc)


def lead_iteration(process: Any, kp: float, phase_margin: float = 60.0,
                   alpha: float = ALPHA_002, w_max: float | None = None,
                   max_steps: int = MAX_LEAD_STEPS) -> tuple[LeadStep, ...]:
    """[Ikonen] §1.2: ``ω_max`` first at ``w_max`` (default: the crossover of the P loop ``kp``),
    then at the mean of the previous ω_max and the new crossover, until the loop with the
    gain ``kp`` has ``phase_margin`` [deg] and is stable, or ω_max stops moving, or
    ``max_steps``. Returns every step; the last one met the target if its margin is at
    least ``phase_margin``."""
    if w_max is None:
        w_max = _margin(loop_margins(process, kp))[1]
    steps: list[LeadStep] = []
    for _ in range(max_steps):
        td = lead_time(w_max, alpha)
        pm, wc = _margin(loop_margins(process, kp, td, alpha))
        steps.append(LeadStep(w_max, td, pm, wc))
        if pm >= phase_margin and loop_stable(process, kp, td, alpha):
            break
        w_next = 0.5 * (w_max + wc)
        if not math.isfinite(w_next) or abs(w_next - w_max) <= 1e-12 * w_max:
            break
        w_max = w_next
    return tuple(steps)


def design_pd(process: Any, error: float = 0.05, phase_margin: float = 60.0,
              alpha: float = ALPHA_002) -> Design:
    """[Ikonen] §1.1–1.2: the P gain for ``error``, then the lead iteration
    (:func:`lead_iteration`) to ``phase_margin`` [deg]; no lead if the P loop already has
    it. ``ConfigError`` if the lead cannot reach it."""
    p = design_p(process, error, alpha, check=False)
    if p.phase_margin >= phase_margin and loop_stable(process, p.kp):
        return p
    steps = lead_iteration(process, p.kp, phase_margin, alpha, p.p_wc)
    last = steps[-1]
    if last.phase_margin >= phase_margin and loop_stable(process, p.kp, last.td, alpha):
        return replace(p, td=last.td, phase_margin=last.phase_margin, wc=last.wc,
                       lead_steps=steps)
    best = max(s.phase_margin for s in steps)
    raise ConfigError(f'tuning.phase_margin: {phase_margin:g} deg is out of reach of the lead '
                      f'(lead_lag.alpha {alpha:g}: at most {lead_max_phase(alpha):.1f} deg of '
                      f'lead) with the gain {p.kp:.6g} that tuning.steady_state_error '
                      f'{error:g} needs; the lead iteration reached {best:.1f} deg; allow a '
                      'lower phase margin, a larger error or a smaller alpha, or use '
                      'tuning.kind pi')


def design_pi(process: Any, phase_margin: float = 60.0, ratio: float = 10.0) -> Design:
    """[Ikonen] §1.3: the P gain that puts the P loop's crossover ``w_p`` where, with the integral
    corner ``1/Ti = w_p/ratio`` (:func:`integral_time`), the PI loop has ``phase_margin``
    [deg] ([Ikonen] lowered the gain by eye to kp 2 and got 57.1°)."""
    g = process_response(process)
    corners = [c for c in g.corners if c > 0.0 and math.isfinite(c)] or [1.0]

    def margin_at(w_p: float) -> float:
        kp = 1.0 / float(abs(g(w_p)))
        return _margin(loop_margins(g, kp, 0.0, ALPHA_002, ratio / w_p))[0] - phase_margin

    low = min(corners) * 1e-4
    if not margin_at(low) > 0.0:
        raise ConfigError(f'tuning.phase_margin: {phase_margin:g} deg is more than a PI with '
                          f'the integral corner {ratio:g} times below the crossover can give '
                          f'on this process; allowed below '
                          f'{phase_margin + margin_at(low):.1f} deg')
    high = low
    while margin_at(high) > 0.0:
        high *= 10.0
        if high > max(corners) * 1e6:
            raise ConfigError(f'tuning.model: the process without dead time keeps the PI '
                              f'loop above {phase_margin:g} deg phase margin at every gain, '
                              'so [Ikonen] fixes no gain; give tuning.dead_time or use tuning.model '
                              'sopdt')
    w_p = brentq(margin_at, high / 10.0, high, xtol=1e-14, rtol=1e-12)
    kp, ti = 1.0 / float(abs(g(w_p))), integral_time(w_p, ratio)
    pm, wc = _margin(loop_margins(g, kp, 0.0, ALPHA_002, ti))
    if not loop_stable(g, kp, 0.0, ALPHA_002, ti):
        raise ConfigError(f'tuning.phase_margin: the PI design for {phase_margin:g} deg is '
                          'unstable on this process; change the target')
    return Design(kp, 0.0, ti, pm, wc, pi_gain=kp, pi_wc=w_p)


def design_pid(process: Any, error: float = 0.05, phase_margin: float = 60.0,
               ratio: float = 10.0, alpha: float = ALPHA_002) -> Design:
    """[Ikonen] §1.4: series PID = PD·PI (:func:`design_pd`, :func:`design_pi`), the gain the
    mean of the two designed gains ([Ikonen]: (9.5 + 2)/2 = 5.75)."""
    pd = design_pd(process, error, phase_margin, alpha)
    pi = design_pi(process, phase_margin, ratio)
    kp = 0.5 * (pd.kp + pi.kp)
    pm, wc = _margin(loop_margins(process, kp, pd.td, alpha, pi.ti))
    if not loop_stable(process, kp, pd.td, alpha, pi.ti):
        raise ConfigError('tuning.kind: the series PID of the PD and PI designs (mean gain '
                          f'{kp:.6g}) is unstable on this model; use tuning.kind pd or pi')
    return replace(pd, kp=kp, ti=pi.ti, phase_margin=pm, wc=wc, pi_gain=pi.kp,
                   pi_wc=pi.pi_wc)


def design(process: Any, kind: str, error: float = 0.05, phase_margin: float = 60.0,
           ratio: float = 10.0, alpha: float = ALPHA_002) -> Design:
    """[Ikonen]'s design of ``kind`` (p, pd, pi, pid) for the continuous ``process`` with the
    steady-state error ``error`` (p, pd, pid), the target ``phase_margin`` [deg], the
    integral corner ``ratio`` times below the crossover and the lead ratio ``alpha``.

    >>> d = design(fr.rational([4.0], [1.0, 3.0, 2.0]), 'pd')
    >>> round(d.kp, 2), round(d.td, 3), round(d.phase_margin, 1), round(d.wc, 1)
    (9.5, 0.294, 70.5, 10.9)
    """
    if kind == 'p':
        return design_p(process, error, alpha)
    if kind == 'pd':
        return design_pd(process, error, phase_margin, alpha)
    if kind == 'pi':
        return design_pi(process, phase_margin, ratio)
    if kind == 'pid':
        return design_pid(process, error, phase_margin, ratio, alpha)
    raise ConfigError(f'tuning.kind: {kind!r} is not designed by [Ikonen]; allowed '
                      + ', '.join(KINDS))


# ============================================================================= report
def report(process: Any, error: float = 0.05, phase_margin: float = 60.0, ratio: float = 10.0,
           alpha: float = ALPHA_002) -> str:
    """The design steps and the four designs for ``process``, in lines (units in the text);
    ``python -m tank_control.core.tuning.design_002`` prints it for [Ikonen]'s process."""
    lines = [f'targets: steady-state error {error:g}, phase margin {phase_margin:g} deg '
             f'(damping {damping_from_phase_margin(phase_margin):.2f}, overshoot '
             f'{100 * overshoot_from_damping(damping_from_phase_margin(phase_margin)):.2f} %); '
             f'5 % overshoot needs damping {damping_from_overshoot(0.05):.3f}, '
             f'{phase_margin_for_overshoot(0.05):.1f} deg',
             f'lead alpha {alpha:g}: largest lead {lead_max_phase(alpha):.2f} deg at '
             f'w_max = 1/(td sqrt(alpha)); integral corner {ratio:g} x below the crossover']
    for kind in KINDS:
        try:
            x = design(process, kind, error, phase_margin, ratio, alpha)
        except ConfigError as e:
            lines.append(f'{kind:3}  refused: {e}')
            continue
        lines.append(f'{kind:3}  kp {x.kp:.4g}  td {x.td:.4g} s  ti {x.ti:.4g} s  '
                     f'PM {x.phase_margin:.2f} deg at {x.wc:.4g} rad/s')
        for s in x.lead_steps if kind == 'pd' else ():
            lines.append(f'     lead step: w_max {s.w_max:.4g} rad/s  td {s.td:.4g} s  '
                         f'PM {s.phase_margin:.2f} deg at {s.wc:.4g} rad/s')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    """``python -m tank_control.core.tuning.design_002 [--num ...] [--den ...] ...``: [Ikonen]'s
    design for a transfer function (default [Ikonen]'s process 4/((s + 1)(s + 2)))."""
    import argparse
    parser = argparse.ArgumentParser(prog='python -m tank_control.core.tuning.design_002',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('--num', type=float, nargs='+', default=[4.0],
                        help='numerator of G(s), highest power first')
    parser.add_argument('--den', type=float, nargs='+', default=[1.0, 3.0, 2.0],
                        help='denominator of G(s), highest power first')
    parser.add_argument('--dead-time', type=float, default=0.0, help='dead time [s]')
    parser.add_argument('--error', type=float, default=0.05,
                        help='steady-state error (fraction of the step)')
    parser.add_argument('--phase-margin', type=float, default=60.0, help='target [deg]')
    parser.add_argument('--ratio', type=float, default=10.0,
                        help='integral corner this many times below the crossover')
    parser.add_argument('--alpha', type=float, default=ALPHA_002, help='lead ratio Tf/Td')
    args = parser.parse_args(argv)
    g = fr.rational(args.num, args.den, args.dead_time)
    print(report(g, args.error, args.phase_margin, args.ratio, args.alpha))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
