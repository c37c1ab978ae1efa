"""PID tuning rules behind one entry point, ``tune(rule, kind, **process)`` (000, 001, 004).

Every rule returns ``{kp, ti, td, b, c}`` in the form of the 2-DOF PID of 000 eq. 19 (``kp`` in
output units per measured unit, ``ti``/``td`` in s, ``b``/``c`` dimensionless; ``None`` where
the rule gives no value). Process arguments: ``gain`` (IPDT k1 [1/s] or FOPDT K),
``dead_time`` [s], ``time_constant`` [s], ``ku``, ``tu`` [s]; ``smith_pi`` also ``n``, ``te``
[s], ``xi``. Unknown or missing arguments, non-positive values and unknown rules or kinds raise
``ValueError`` naming them. Rules: ``mdp``, ``experimental``, ``zn``, ``zn_001``, ``zn_004_q0``,
``zn_004_q1``, ``oppelt``, ``cohen_coon``, ``smith_pi`` — sources and notes: docs/tuning.md.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping

Gains = dict[str, float | None]

PROCESS_ARGS = ('gain', 'dead_time', 'time_constant', 'ku', 'tu', 'te', 'xi', 'n')
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


# ---------------------------------------------------------------- IPDT (000)
def mdp(kind: str, process: Mapping[str, float]) -> Gains:
    """Multiple dominant pole for k1/s·e^(−To·s) (000 eqs. 25–28, 32, 34).

    Exact closed forms (PID kp = 0.78362/(k1·To), td = 0.26289·To); 000's Table 1 used the
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
    """Experimental 2-DOF settings for IPDT (000 eqs. 35–36).

    The PI follows eq. 36, kp = 0.6/(k1·To) (2.4 for 000's example); Table 1 prints 2.5.
    """
    k1, to = _need(process, 'experimental', 'gain', 'dead_time')
    if kind == 'pid':
        return _gains(kp=1.0 / (k1 * to), ti=3.0 * to, td=0.35 * to, b=0.3, c=0.3)        # eq. 35
    if kind == 'pi':
        return _gains(kp=0.6 / (k1 * to), ti=4.15 * to, b=0.25)                            # eq. 36
    raise _bad_kind('experimental', kind, ('pi', 'pid'))


# --------------------------------------------------- ultimate point (001, 004)
# kind → (kp/ku, ti/tu, td/tu)
_ZN = {'p': (0.5, None, None), 'pi': (0.45, 1.0 / 1.2, None), 'pid': (0.6, 0.5, 0.125)}    # 1942
_ZN_001 = {'p': (0.45, None, None), 'pi': (0.45, 0.85, None), 'pid': (0.6, 0.5, 0.12)}   # 001 Table 6.2
_ZN_004 = {'p': (0.5, None, None), 'pi': (0.45, 0.8, None)}                              # 004 Table 3.1
_ZN_004_PID = {'zn_004_q0': (0.75, 0.6, 0.1), 'zn_004_q1': (0.6, 0.5, 0.12)}


def _ultimate(rule: str, table: Mapping[str, tuple], kind: str, process: Mapping[str, float]) -> Gains:
    if kind not in table:
        raise _bad_kind(rule, kind, tuple(table))
    ku, tu = _need(process, rule, 'ku', 'tu')
    fk, fi, fd = table[kind]
    return _gains(kp=fk * ku, ti=None if fi is None else fi * tu, td=None if fd is None else fd * tu)


def zn(kind: str, process: Mapping[str, float]) -> Gains:
    """Classical Ziegler–Nichols ultimate-point rule (Ziegler & Nichols, Trans. ASME 64,
    1942; SPEC-supplement §1.9): P kp = 0.5·Ku; PI 0.45·Ku, ti = Tu/1.2; PID 0.6·Ku,
    ti = Tu/2, td = Tu/8."""
    return _ultimate('zn', _ZN, kind, process)


def zn_001(kind: str, process: Mapping[str, float]) -> Gains:
    """Ziegler–Nichols ultimate-point table, 001 Table 6.2."""
    return _ultimate('zn_001', _ZN_001, kind, process)


def zn_004_q0(kind: str, process: Mapping[str, float]) -> Gains:
    """Ziegler–Nichols, 004 Table 3.1 (PID column q = 0)."""
    return _ultimate('zn_004_q0', {**_ZN_004, 'pid': _ZN_004_PID['zn_004_q0']}, kind, process)


def zn_004_q1(kind: str, process: Mapping[str, float]) -> Gains:
    """Ziegler–Nichols as printed in 004 Table 3.1, PID column q = 1 (td = 0.12·Tu as in
    001 Table 6.2; not the classical Tu/8 of :func:`zn`). The table values are used as
    printed: the PID form 3.2.2 is garbled in our copy of 004."""
    return _ultimate('zn_004_q1', {**_ZN_004, 'pid': _ZN_004_PID['zn_004_q1']}, kind, process)


# ------------------------------------------------------ FOPDT step response
def oppelt(kind: str, process: Mapping[str, float]) -> Gains:
    """Oppelt, 001 Table 6.1, with a = K·L/T from the tangent construction (eq. 6.15)."""
    if kind not in ('p', 'pi', 'pid'):
        raise _bad_kind('oppelt', kind, ('p', 'pi', 'pid'))
    k, t, dead = _need(process, 'oppelt', 'gain', 'time_constant', 'dead_time')
    a = k * dead / t
    if kind == 'p':
        return _gains(kp=1.0 / a)
    if kind == 'pi':
        return _gains(kp=0.8 / a, ti=3.0 * dead)
    return _gains(kp=1.2 / a, ti=2.0 * dead, td=0.42 * dead)


def cohen_coon(kind: str, process: Mapping[str, float]) -> Gains:
    """Classical Cohen–Coon for K/(T·s+1)·e^(−L·s) (004 eqs. 3.4.12–3.4.15).

    004 restates the formulas in Åström–Hägglund's normalised form with τ = L/(L+T); they
    agree to the printed digits except the PI gain, printed 0.9·(1 + 0.92·τ/(1−τ)), where the
    classical formula 0.9 + L/(12T) = 0.9·(1 + 0.093·τ/(1−τ)) is used.
    """
    if kind not in ('p', 'pi', 'pd', 'pid'):
        raise _bad_kind('cohen_coon', kind, ('p', 'pi', 'pd', 'pid'))
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
    """PI primary for a Smith predictor on K/(T·s+1)^n (004 eqs. 3.6.7, 3.6.9).

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


RULES: dict[str, Callable[[str, Mapping[str, float]], Gains]] = {
    'mdp': mdp, 'experimental': experimental, 'zn': zn, 'zn_001': zn_001, 'zn_004_q0': zn_004_q0,
    'zn_004_q1': zn_004_q1, 'oppelt': oppelt, 'cohen_coon': cohen_coon, 'smith_pi': smith_pi,
}


def _bad_kind(rule: str, kind: str, allowed: tuple[str, ...]) -> ValueError:
    return ValueError(f"tune: kind {kind!r} is not available for rule '{rule}'; allowed "
                      + ', '.join(allowed))


def tune(rule: str, kind: str, **process: float) -> Gains:
    """Controller settings ``{kp, ti, td, b, c}`` from a named rule (rules: docs/tuning.md).

    >>> round(tune('mdp', 'pid', gain=0.05, dead_time=5.0)['kp'], 2)
    3.13
    """
    if rule not in RULES:
        raise ValueError(f'tune: unknown rule {rule!r}; allowed ' + ', '.join(RULES))
    for name in process:
        if name not in PROCESS_ARGS:
            raise ValueError(f'tune: unknown process argument {name!r}; allowed ' + ', '.join(PROCESS_ARGS))
    return RULES[rule](kind, process)
