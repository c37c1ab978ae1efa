"""PID tuning rules behind one entry point, ``tune(rule, kind, **process)`` ([Viteckova],
[DeadTimeNotes], [Precup2013]).

Every rule returns ``{kp, ti, td, b, c}`` in the form of the 2-DOF PID of [Viteckova] eq. 19 (``kp`` in
output units per measured unit, ``ti``/``td`` in s, ``b``/``c`` dimensionless; ``None`` where
the rule gives no value), as a :class:`TuneResult` that also carries the rule's source, the
process model it was designed on and the predicted margins on it. Process arguments: ``gain``
(IPDT k1 [1/s], FOPDT/SOPDT K), ``dead_time`` [s], ``time_constant`` [s], ``time_constant2``
[s] (SOPDT), ``model``, ``ku``, ``tu`` [s]; ``smith_pi`` also ``n``, ``te`` [s], ``xi`` (also
``wang``'s damping); design
targets ``ms``, ``mt``, ``tau_c`` [s], ``gain_margin``, ``phase_margin`` [deg], ``r``; the
implemented loop ``sample_time`` [s], ``filter_n``. Unknown or missing arguments, non-positive
values and unknown rules or kinds raise ``ValueError`` naming them. Rules: ``mdp``,
``experimental``, ``zn``, ``zn_001``, ``zn_004_q0``, ``zn_004_q1``, ``oppelt``, ``cohen_coon``,
``smith_pi``, ``ms``, ``amigo``, ``simc``, ``lambda``, ``ho``, ``tan``, ``wang`` — sources and notes:
docs/tuning.md.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from functools import lru_cache
from typing import Any, overload

from tank_control.core.tuning.model import KINDS as MODEL_KINDS, ProcessModel

Gains = dict[str, float | None]

PROCESS_ARGS = ('gain', 'dead_time', 'time_constant', 'time_constant2', 'model', 'ku', 'tu',
                'te', 'xi', 'n', 'ms', 'mt', 'tau_c', 'gain_margin', 'phase_margin', 'r',
                'sample_time', 'filter_n')
SQRT2, SQRT3 = math.sqrt(2.0), math.sqrt(3.0)


def _gains(kp: float, ti: float | None = None, td: float | None = None,
           b: float | None = None, c: float | None = None) -> Gains:
    return {'kp': kp, 'ti': ti, 'td': td, 'b': b, 'c': c}


def _need(process: Mapping[str, float], rule: str, *names: str) -> list[float]:
    """The named process arguments, checked present, finite and positive
    (``gain`` may be negative: a reverse-acting process gives a negative kp)."""
    values = []
    for name in names:
        if name not in process:
            raise ValueError(f"tune: rule '{rule}' needs the process argument '{name}'")
        value = process[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f'tune: {name} = {value!r} is not a finite number')
        if name == 'gain':
            if value == 0.0:
                raise ValueError('tune: gain must be non-zero; allowed (-inf, 0) or (0, inf)')
        elif value <= 0.0:
            raise ValueError(f'tune: {name} = {value!r} must be > 0; allowed (0, inf)')
        values.append(float(value))
    return values


# ---------------------------------------------------------------- IPDT ([Viteckova])
def mdp(kind: str, process: Mapping[str, float]) -> Gains:
    """Multiple dominant pole for k1/s·e^(−To·s) ([Viteckova] eqs. 25–28, 32, 34).

    Exact closed forms (PID kp = 0.78362/(k1·To), td = 0.26289·To); [Viteckova]'s Table 1 used the
    rounded 0.784 and 0.263, hence its kp = 3.14 and td = 1.32 for the exact 3.134 and 1.314.
    """
    k1, to = _need(process, 'mdp', 'gain', 'dead_time')
    if kind == 'pid':   # quadruple pole s* = −(3 − √3)/To (eq. 25)
        return _gains(kp=6.0 * (2.0 * SQRT3 - 3.0) * math.exp(SQRT3 - 3.0) / (k1 * to),   # eq. 26
                      ti=(2.0 + SQRT3) * to, td=(3.0 + SQRT3) / 18.0 * to,
                      b=(3.0 - SQRT3) / 3.0, c=(3.0 - SQRT3) / 2.0)                        # eq. 32
    if kind == 'pi':    # triple pole s* = −(2 − √2)/To (eq. 27)
        return _gains(kp=2.0 * (SQRT2 - 1.0) * math.exp(SQRT2 - 2.0) / (k1 * to),          # eq. 28
                      ti=(3.0 + 2.0 * SQRT2) * to, b=(2.0 - SQRT2) / 2.0)                  # eq. 34
    raise _bad_kind('mdp', kind, ('pi', 'pid'))


def experimental(kind: str, process: Mapping[str, float]) -> Gains:
    """Experimental 2-DOF settings for IPDT ([Viteckova] eqs. 35–36).

    The PI follows eq. 36, kp = 0.6/(k1·To) (2.4 for [Viteckova]'s example); Table 1 prints 2.5.
    """
    k1, to = _need(process, 'experimental', 'gain', 'dead_time')
    if kind == 'pid':
        return _gains(kp=1.0 / (k1 * to), ti=3.0 * to, td=0.35 * to, b=0.3, c=0.3)        # eq. 35
    if kind == 'pi':
        return _gains(kp=0.6 / (k1 * to), ti=4.15 * to, b=0.25)                            # eq. 36
    raise _bad_kind('experimental', kind, ('pi', 'pid'))


# --------------------------------------------------- ultimate point ([DeadTimeNotes], [Precup2013])
# kind → (kp/ku, ti/tu, td/tu)
_ZN = {'p': (0.5, None, None), 'pi': (0.45, 1.0 / 1.2, None), 'pid': (0.6, 0.5, 0.125)}    # 1942
_ZN_001 = {'p': (0.45, None, None), 'pi': (0.45, 0.85, None), 'pid': (0.6, 0.5, 0.12)}   # [DeadTimeNotes] Table 6.2
_ZN_004 = {'p': (0.5, None, None), 'pi': (0.45, 0.8, None)}                              # [Precup2013] Table 3.1
_ZN_004_PID = {'zn_004_q0': (0.75, 0.6, 0.1), 'zn_004_q1': (0.6, 0.5, 0.12)}


def _ultimate(rule: str, table: Mapping[str, tuple], kind: str, process: Mapping[str, float]) -> Gains:
    if kind not in table:
        raise _bad_kind(rule, kind, tuple(table))
    ku, tu = _need(process, rule, 'ku', 'tu')
    fk, fi, fd = table[kind]
    return _gains(kp=fk * ku, ti=None if fi is None else fi * tu, td=None if fd is None else fd * tu)


def zn(kind: str, process: Mapping[str, float]) -> Gains:
    """Classical Ziegler–Nichols ultimate-point rule (Ziegler & Nichols, Trans. ASME 64,
    1942; [ZieglerNichols1942]): P kp = 0.5·Ku; PI 0.45·Ku, ti = Tu/1.2; PID 0.6·Ku,
    ti = Tu/2, td = Tu/8."""
    return _ultimate('zn', _ZN, kind, process)


def zn_001(kind: str, process: Mapping[str, float]) -> Gains:
    """Ziegler–Nichols ultimate-point table, [DeadTimeNotes] Table 6.2."""
    return _ultimate('zn_001', _ZN_001, kind, process)


def zn_004_q0(kind: str, process: Mapping[str, float]) -> Gains:
    """Ziegler–Nichols, [Precup2013] Table 3.1 (PID column q = 0)."""
    return _ultimate('zn_004_q0', {**_ZN_004, 'pid': _ZN_004_PID['zn_004_q0']}, kind, process)


def zn_004_q1(kind: str, process: Mapping[str, float]) -> Gains:
    """Ziegler–Nichols as printed in [Precup2013] Table 3.1, PID column q = 1 (td = 0.12·Tu as in
    [DeadTimeNotes] Table 6.2; not the classical Tu/8 of :func:`zn`). The table values are used as
    printed: the PID form 3.2.2 is garbled in our copy of [Precup2013]."""
    return _ultimate('zn_004_q1', {**_ZN_004, 'pid': _ZN_004_PID['zn_004_q1']}, kind, process)


# ------------------------------------------------------ FOPDT step response
def _fopdt_only(process: Mapping[str, Any], rule: str) -> None:
    """An FOPDT rule refuses another model rather than ignore part of it (T2 of an SOPDT)."""
    kind = process.get('model', 'sopdt' if process.get('time_constant2') else 'fopdt')
    if kind != 'fopdt':
        raise ValueError(f'tune: rule {rule!r} is for an FOPDT model, not model = {kind!r}; '
                         'give the FOPDT (gain, time_constant, dead_time)')


def oppelt(kind: str, process: Mapping[str, float]) -> Gains:
    """Oppelt, [DeadTimeNotes] Table 6.1, with a = K·L/T from the tangent construction (eq. 6.15)."""
    if kind not in ('p', 'pi', 'pid'):
        raise _bad_kind('oppelt', kind, ('p', 'pi', 'pid'))
    _fopdt_only(process, 'oppelt')
    k, t, dead = _need(process, 'oppelt', 'gain', 'time_constant', 'dead_time')
    a = k * dead / t
    if kind == 'p':
        return _gains(kp=1.0 / a)
    if kind == 'pi':
        return _gains(kp=0.8 / a, ti=3.0 * dead)
    return _gains(kp=1.2 / a, ti=2.0 * dead, td=0.42 * dead)


def cohen_coon(kind: str, process: Mapping[str, float]) -> Gains:
    """Classical Cohen–Coon for K/(T·s+1)·e^(−L·s) ([Precup2013] eqs. 3.4.12–3.4.15).

    [Precup2013] restates the formulas in Åström–Hägglund's normalised form with τ = L/(L+T); they
    agree to the printed digits except the PI gain, printed 0.9·(1 + 0.92·τ/(1−τ)), where the
    classical formula 0.9 + L/(12T) = 0.9·(1 + 0.093·τ/(1−τ)) is used.
    """
    if kind not in ('p', 'pi', 'pd', 'pid'):
        raise _bad_kind('cohen_coon', kind, ('p', 'pi', 'pd', 'pid'))
    _fopdt_only(process, 'cohen_coon')
    k, t, dead = _need(process, 'cohen_coon', 'gain', 'time_constant', 'dead_time')
    r = dead / t                      # L/T = τ/(1 − τ)
    base = t / (k * dead)             # 1/a
    if kind == 'p':                   # 3.4.13
        return _gains(kp=base * (1.0 + r / 3.0))
    if kind == 'pi':                  # 3.4.14
        return _gains(kp=base * (0.9 + r / 12.0), ti=dead * (30.0 + 3.0 * r) / (9.0 + 20.0 * r))
    if kind == 'pd':                  # 3.4.15
        return _gains(kp=base * (1.25 + r / 6.0), td=dead * (6.0 - 2.0 * r) / (22.0 + 3.0 * r))
    return _gains(kp=base * (4.0 / 3.0 + r / 4.0),                                      # 3.4.12
                  ti=dead * (32.0 + 6.0 * r) / (13.0 + 8.0 * r), td=dead * 4.0 / (11.0 + 2.0 * r))


# ------------------------------------------------------------- Smith primary
def smith_pi(kind: str, process: Mapping[str, float]) -> Gains:
    """PI primary for a Smith predictor on K/(T·s+1)^n ([Precup2013] eqs. 3.6.7, 3.6.9).

    n = 1: kp = T/(K·te), ti = T (te = desired closed-loop time constant, recommended
    (0.2…1)·T); n = 2: kp = 1/(4·xi²·K), ti = T (xi recommended in [0.5, 1]).
    """
    if kind != 'pi':
        raise _bad_kind('smith_pi', kind, ('pi',))
    order = process.get('n', 1)
    if order not in (1, 2):
        raise ValueError(f'tune: n = {order!r} is not a model order of smith_pi; allowed 1 or 2')
    k, t = _need(process, 'smith_pi', 'gain', 'time_constant')
    if order == 1:
        (te,) = _need(process, 'smith_pi', 'te')
        return _gains(kp=t / (k * te), ti=t)                    # eq. 3.6.7
    (xi,) = _need(process, 'smith_pi', 'xi')
    return _gains(kp=1.0 / (4.0 * xi * xi * k), ti=t)           # eq. 3.6.9


# ------------------------------------------------------ model-based robust rules
def _model(process: Mapping[str, Any], rule: str) -> ProcessModel:
    """The FOPDT/IPDT/SOPDT of the process arguments (``model`` or inferred), gain magnitude."""
    kind = process.get('model')
    if kind is None:
        kind = ('sopdt' if process.get('time_constant2') else
                'fopdt' if process.get('time_constant') else 'ipdt')
    if kind not in MODEL_KINDS:
        raise ValueError(f'tune: model = {kind!r} is not a model kind; allowed '
                         + ', '.join(MODEL_KINDS))
    names = {'ipdt': ('gain', 'dead_time'), 'fopdt': ('gain', 'time_constant', 'dead_time'),
             'sopdt': ('gain', 'time_constant', 'time_constant2', 'dead_time')}[kind]
    values = dict(zip(names, _need(process, rule, *names)))
    t1, t2 = values.get('time_constant', 0.0), values.get('time_constant2', 0.0)
    return ProcessModel(kind, abs(values['gain']), values['dead_time'], max(t1, t2), min(t1, t2))


def _sign(process: Mapping[str, Any]) -> float:
    return -1.0 if process.get('gain', 1.0) < 0 else 1.0


def _half_rule(model: ProcessModel) -> ProcessModel:
    """Skogestad's half rule (2003): the SOPDT's smaller lag T2 is split, half to the
    dead time, half to the larger lag: FOPDT T = T1 + T2/2, L = L + T2/2."""
    if model.kind != 'sopdt':
        return model
    return ProcessModel('fopdt', model.gain, model.dead_time + model.time_constant2 / 2.0,
                        model.time_constant + model.time_constant2 / 2.0)


@overload
def _optional(process: Mapping[str, Any], name: str, default: float) -> float: ...
@overload
def _optional(process: Mapping[str, Any], name: str, default: None) -> float | None: ...


def _optional(process: Mapping[str, Any], name: str, default: float | None) -> float | None:
    if name not in process:
        return default
    return _need(process, 'tune', name)[0]


def _in_kinds(rule: str, kind: str, allowed: tuple[str, ...]) -> None:
    if kind not in allowed:
        raise _bad_kind(rule, kind, allowed)


def ms(kind: str, process: Mapping[str, Any]) -> Gains:
    """Largest integral gain subject to Ms ≤ ``ms`` ([Precup2013] §3.4.2, eq. 3.4.7; see
    ``core/tuning/robust.py``)."""
    _in_kinds('ms', kind, ('pi', 'pid'))
    model = _model(process, 'ms')
    target = _optional(process, 'ms', 1.4)
    mt = _optional(process, 'mt', None)
    h = _optional(process, 'sample_time', None)
    n = _optional(process, 'filter_n', 10.0)
    design = _ms_design(model, kind, target, mt, h, n)
    return _gains(kp=_sign(process) * design.kp, ti=design.ti,
                  td=design.td if kind == 'pid' else None, b=design.b,
                  c=design.c if kind == 'pid' else None)


@lru_cache(maxsize=32)
def _ms_design(model: ProcessModel, kind: str, target: float, mt: float | None,
               h: float | None, n: float) -> Any:
    """The Ms design is a pure function of its arguments; memoised because a node resolves
    its settings several times per parameter change."""
    from tank_control.core.tuning.robust import ms_design
    return ms_design(model, kind, target, mt, h, n)


def amigo(kind: str, process: Mapping[str, Any]) -> Gains:
    """AMIGO PI/PID (Åström & Hägglund 2004, 2006; see module doc)."""
    _in_kinds('amigo', kind, ('pi', 'pid'))
    model = _half_rule(_model(process, 'amigo'))
    k, dead = model.gain, model.dead_time
    if dead <= 0:
        raise ValueError('tune: amigo needs dead_time > 0')
    if model.kind == 'ipdt':
        if kind == 'pi':
            return _gains(kp=_sign(process) * 0.35 / (k * dead), ti=13.4 * dead, b=0.0)
        return _gains(kp=_sign(process) * 0.45 / (k * dead), ti=8.0 * dead, td=0.5 * dead,
                      b=0.0, c=0.0)
    t = model.time_constant
    b = 0.0 if dead / (dead + t) <= 0.5 else 1.0
    if kind == 'pi':
        kp = 0.15 / k + (0.35 - dead * t / (dead + t) ** 2) * t / (k * dead)
        ti = 0.35 * dead + 13.0 * dead * t * t / (t * t + 12.0 * dead * t + 7.0 * dead * dead)
        return _gains(kp=_sign(process) * kp, ti=ti, b=b)
    kp = (0.2 + 0.45 * t / dead) / k
    ti = (0.4 * dead + 0.8 * t) / (dead + 0.1 * t) * dead
    td = 0.5 * dead * t / (0.3 * dead + t)
    return _gains(kp=_sign(process) * kp, ti=ti, td=td, b=b, c=0.0)


def simc(kind: str, process: Mapping[str, Any]) -> Gains:
    """SIMC (Skogestad 2003; see module doc)."""
    _in_kinds('simc', kind, ('pi', 'pid'))
    model = _model(process, 'simc')
    dead = model.dead_time
    tc = _optional(process, 'tau_c', dead)
    if tc <= 0:
        raise ValueError('tune: simc needs tau_c > 0 (or dead_time > 0 for the default tau_c = L)')
    sign = _sign(process)
    if kind == 'pid':
        if model.kind != 'sopdt':
            raise ValueError(f"tune: kind 'pid' of rule 'simc' needs a second-order model "
                             f"(sopdt, its τD = T2); the {model.kind} model gives pi")
        kc = model.time_constant / (model.gain * (tc + dead))
        tau_i = min(model.time_constant, 4.0 * (tc + dead))
        tau_d = model.time_constant2
        return _gains(kp=sign * kc * (1.0 + tau_d / tau_i), ti=tau_i + tau_d,
                      td=tau_i * tau_d / (tau_i + tau_d))
    model = _half_rule(model)
    if model.kind == 'ipdt':
        return _gains(kp=sign / (model.gain * (tc + dead)), ti=4.0 * (tc + dead))
    t = model.time_constant
    dead = model.dead_time
    return _gains(kp=sign * t / (model.gain * (tc + dead)), ti=min(t, 4.0 * (tc + dead)))


def lambda_(kind: str, process: Mapping[str, Any]) -> Gains:
    """Lambda (IMC) PI (see module doc)."""
    _in_kinds('lambda', kind, ('pi',))
    model = _half_rule(_model(process, 'lambda'))
    sign, dead = _sign(process), model.dead_time
    if model.kind == 'ipdt':
        if 'tau_c' not in process:
            raise ValueError("tune: rule 'lambda' on an IPDT needs the process argument "
                             "'tau_c' (the closed-loop time constant λ)")
        lam = _need(process, 'lambda', 'tau_c')[0]
        return _gains(kp=sign * (2 * lam + dead) / (model.gain * (lam + dead) ** 2),
                      ti=2 * lam + dead)
    t = model.time_constant
    lam = _optional(process, 'tau_c', t)
    return _gains(kp=sign * t / (model.gain * (lam + dead)), ti=t)


def _margin_spec(process: Mapping[str, Any]) -> tuple[float, float]:
    ar = _optional(process, 'gain_margin', 3.0)
    pm = _optional(process, 'phase_margin', 60.0)
    if ar <= 1.0:
        raise ValueError(f'tune: gain_margin = {ar:g} must be > 1; allowed (1, inf)')
    if pm >= 90.0:
        raise ValueError(f'tune: phase_margin = {pm:g} must be < 90 deg; allowed (0, 90)')
    return ar, math.radians(pm)


def ho(kind: str, process: Mapping[str, Any]) -> Gains:
    """PI from gain and phase margins (Ho, Hang & Cao 1995; [Precup2013] eqs. 3.4.16–3.4.18)."""
    _in_kinds('ho', kind, ('pi',))
    model = _half_rule(_model(process, 'ho'))
    ar, phi = _margin_spec(process)
    dead = model.dead_time
    if dead <= 0:
        raise ValueError('tune: ho needs dead_time > 0 ([Precup2013] eq. 3.4.18 divides by it)')
    wp = (ar * phi + 0.5 * math.pi * ar * (ar - 1.0)) / ((ar * ar - 1.0) * dead)   # 3.4.18
    inv_t = 0.0 if model.kind == 'ipdt' else 1.0 / model.time_constant
    denom = 2.0 * wp - 4.0 * wp * wp * dead / math.pi + inv_t                        # 3.4.17
    if denom <= 1e-9 * wp:
        raise ValueError(f'tune: gain_margin {ar:g} and phase_margin {math.degrees(phi):g} deg '
                         'are incompatible on this process ([Precup2013] eq. 3.4.17 gives no finite '
                         'ti > 0)')
    if model.kind == 'ipdt':
        kp = wp / (ar * model.gain)             # limit T → ∞ of ω_P·T/(A_r·K), K = k1·T
    else:
        kp = wp * model.time_constant / (ar * model.gain)                             # 3.4.17
    return _gains(kp=_sign(process) * kp, ti=1.0 / denom)


def tan(kind: str, process: Mapping[str, Any]) -> Gains:
    """Two-point PI of Tan, Lee & Wang ([Precup2013] eqs. 3.4.19, 3.4.22; see module doc)."""
    if kind == 'pid':
        raise ValueError("tune: kind 'pid' is not available for rule 'tan': [Precup2013] eqs. "
                         '3.4.20-3.4.21 are garbled in our copy; allowed pi')
    _in_kinds('tan', kind, ('pi',))
    model = _model(process, 'tan')
    ar, _ = _margin_spec(process)
    if 'r' in process:
        r = _need(process, 'tan', 'r')[0]
        if r >= 1.0:
            raise ValueError(f'tune: r = {r:g} must be < 1; allowed (0, 1)')
    else:
        theta = model.dead_time / model.lag if math.isfinite(model.lag) else math.inf
        r = 0.8 if theta < 0.5 else 0.5                                               # 3.4.22
    g = model.response()
    w = r * model.ultimate_point().wu
    value = complex(g(w))
    from tank_control.core.analysis.frequency import bode
    phase = math.radians(float(bode(g, [w])[2][0]))
    if not -math.pi < phase < -math.pi / 2:
        raise ValueError(f'tune: the process phase at r*wu is {math.degrees(phase):.1f} deg; '
                         'rule tan needs it in (-180, -90) deg (choose another r)')
    ti = 1.0 / (w * math.tan(math.pi + phase))
    kp = w * ti / (ar * abs(value) * math.sqrt((w * ti) ** 2 + 1.0))
    return _gains(kp=_sign(process) * kp, ti=ti)


def wang(kind: str, process: Mapping[str, Any]) -> Gains:
    """PI/PID fitted to the desired closed loop ωn²·e^(−L·s)/(s² + 2ξωn·s + ωn²) with
    ωn·L = 2 and ξ = ``xi`` (default 0.707) by least squares over the model's frequency
    response ([Precup2013] eqs. 3.5.1–3.5.7; ``core/tuning/loop_fit.py``)."""
    _in_kinds('wang', kind, ('pi', 'pid'))
    from tank_control.core.tuning.loop_fit import design
    model = _model(process, 'wang')
    if model.kind == 'ipdt':
        raise ValueError('tune: rule wang needs a self-regulating model (fopdt or sopdt): with '
                         'an integrating process the fit leaves no integral action')
    g = model.response()
    fit = design(lambda w: g(w), model.dead_time, kind, zeta=_optional(process, 'xi', 0.707))
    return _gains(kp=_sign(process) * fit.kp, ti=fit.ti, td=fit.td if kind == 'pid' else None)


RULES: dict[str, Callable[[str, Mapping[str, float]], Gains]] = {
    'mdp': mdp, 'experimental': experimental, 'zn': zn, 'zn_001': zn_001, 'zn_004_q0': zn_004_q0,
    'zn_004_q1': zn_004_q1, 'oppelt': oppelt, 'cohen_coon': cohen_coon, 'smith_pi': smith_pi,
    'ms': ms, 'amigo': amigo, 'simc': simc, 'lambda': lambda_, 'ho': ho, 'tan': tan,
    'wang': wang,
}

SOURCES: dict[str, str] = {
    'mdp': '[Viteckova] eqs. 25-28, 32, 34 (multiple dominant pole, IPDT)',
    'experimental': '[Viteckova] eqs. 35-36 (experimental 2-DOF settings, IPDT)',
    'zn': 'Ziegler & Nichols 1942, ultimate point',
    'zn_001': '[DeadTimeNotes] Table 6.2 (Ziegler-Nichols ultimate point)',
    'zn_004_q0': '[Precup2013] Table 3.1, q = 0',
    'zn_004_q1': '[Precup2013] Table 3.1, q = 1',
    'oppelt': '[DeadTimeNotes] Table 6.1 (Oppelt, step response)',
    'cohen_coon': 'Cohen & Coon 1953; [Precup2013] eqs. 3.4.12-3.4.15',
    'smith_pi': '[Precup2013] eqs. 3.6.7, 3.6.9 (Smith predictor primary)',
    'ms': 'largest integral gain with Ms bounded: the kappa-tau idea of [Precup2013] §3.4.2 '
          '(Åström & Hägglund 1995) by optimisation',
    'amigo': 'AMIGO, Åström & Hägglund 2004 (J. Process Control 14)',
    'simc': 'SIMC, Skogestad 2003 (J. Process Control 13)',
    'lambda': 'lambda/IMC PI (Rivera, Morari & Skogestad 1986; Chien & Fruehauf 1990)',
    'ho': 'gain and phase margin PI, Ho, Hang & Cao 1995 ([Precup2013] eqs. 3.4.16-3.4.18)',
    'tan': 'two-point PI, Tan, Lee & Wang 1996 ([Precup2013] eqs. 3.4.19, 3.4.22)',
    'wang': 'PI/PID fitted to a desired closed loop, Wang 1997 ([Precup2013] eqs. 3.5.1-3.5.7)',
}
MODEL_RULES = ('ms', 'amigo', 'simc', 'lambda', 'ho', 'tan', 'wang')
"""Rules designed on a process model (FOPDT, IPDT, SOPDT)."""
COSTLY_RULES = ('ms',)
"""Rules whose design is a numerical search (tenths of a second to seconds): a live node in wall
mode runs it off the sampling path (nodes/live_derive.py)."""


def _bad_kind(rule: str, kind: str, allowed: tuple[str, ...]) -> ValueError:
    return ValueError(f"tune: kind {kind!r} is not available for rule '{rule}'; allowed "
                      + ', '.join(allowed))


class TuneResult(dict):
    """``{kp, ti, td, b, c}`` of a rule (a plain dict of these five keys) that also says what
    it is: ``rule``, ``kind``, ``source`` (the document or paper), ``model`` (the
    :class:`~tank_control.core.tuning.model.ProcessModel` it was designed on, or None),
    ``sample_time`` and ``filter_n`` of the loop it is predicted for, and :attr:`margins`."""

    def __init__(self, gains: Gains, rule: str, kind: str, model: ProcessModel | None,
                 sample_time: float | None, filter_n: float) -> None:
        super().__init__(gains)
        self.rule, self.kind, self.source = rule, kind, SOURCES.get(rule, '')
        self.model, self.sample_time, self.filter_n = model, sample_time, filter_n
        self._margins: dict[str, Any] | None = None

    @property
    def margins(self) -> dict[str, Any] | None:
        """Predicted robustness on :attr:`model` (None without a model): ``gain_margin``,
        ``phase_margin`` [deg], ``ms``, ``mt``, ``wc``/``w180`` [rad/s], ``delay_margin``
        [s], ``stable`` (Nyquist with the exact delay), ``setpoint_peak`` — of the
        implemented discrete loop (exact ZOH plant, ``Pid2Dof``) when ``sample_time`` is
        set, else of the continuous loop (``core/analysis/frequency.tuning_report``)."""
        if self.model is None:
            return None
        if self._margins is None:
            from tank_control.core.analysis.frequency import tuning_report
            g = {k: (abs(v) if k == 'kp' else v) for k, v in self.items()}
            self._margins = tuning_report(self.model.response(self.sample_time), g['kp'],
                                          g['ti'], g['td'], g['b'], g['c'], self.filter_n)
        return self._margins

    def explain(self) -> str:
        """What the result is, in a few lines: rule and source, gains, predicted margins."""
        def num(value: float | None) -> str:
            return '-' if value is None else f'{value:.4g}'
        lines = [f'rule {self.rule} ({self.source}), {self.kind}: '
                 + ', '.join(f'{k} {num(self[k])}' for k in ('kp', 'ti', 'td', 'b', 'c'))]
        m = self.margins
        if m is not None and self.model is not None:      # margins need a model
            loop = (f'discrete loop, h = {self.sample_time:g} s' if self.sample_time
                    else 'continuous loop')
            lines.append(f'predicted on {self.model.describe()} ({loop}): '
                         f"{'stable' if m['stable'] else 'UNSTABLE'}, Ms {m['ms']:.3f}, "
                         f"Mt {m['mt']:.3f}, GM {m['gain_margin']:.3g}, "
                         f"PM {m['phase_margin']:.1f} deg, delay margin "
                         f"{m['delay_margin']:.3g} s, crossover {m['wc']:.3g} rad/s")
        return '\n'.join(lines)


def tune(rule: str, kind: str, **process: Any) -> TuneResult:
    """Controller settings ``{kp, ti, td, b, c}`` from a named rule (rules: docs/tuning.md), as a
    :class:`TuneResult` that also carries the model and the predicted margins.

    >>> round(tune('mdp', 'pid', gain=0.05, dead_time=5.0)['kp'], 2)
    3.13
    """
    if rule not in RULES:
        raise ValueError(f'tune: unknown rule {rule!r}; allowed ' + ', '.join(RULES))
    for name in process:
        if name not in PROCESS_ARGS:
            raise ValueError(f'tune: unknown process argument {name!r}; allowed ' + ', '.join(PROCESS_ARGS))
    try:
        gains = RULES[rule](kind, process)
    except ArithmeticError as exc:      # e.g. k1·To underflowing to 0 in a quotient
        raise ValueError(f'tune: rule {rule!r} cannot compute gains from these process '
                         f'arguments ({type(exc).__name__}: {exc})') from None
    for name, value in gains.items():
        if value is not None and not math.isfinite(value):
            raise ValueError(f'tune: rule {rule!r} gives the non-finite {name} = {value!r} for '
                             'these process arguments')
    model = None
    try:
        if rule in MODEL_RULES or rule in ('oppelt', 'cohen_coon') or (
                rule in ('mdp', 'experimental') and 'model' not in process):
            args = dict(process)
            if rule in ('mdp', 'experimental'):
                args['model'] = 'ipdt'
            elif rule in ('oppelt', 'cohen_coon'):
                args['model'] = 'fopdt'
            model = _model(args, rule)
        elif {'gain', 'dead_time'} <= set(process):
            model = _model(process, rule)
    except ValueError:
        model = None
    h = process.get('sample_time') or None
    return TuneResult(gains, rule, kind, model, h, float(process.get('filter_n', 10.0)))
