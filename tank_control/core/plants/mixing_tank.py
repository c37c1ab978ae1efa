"""Nonlinear mixing tank with transport delays ([Michalski2021] §1). Units: cm, cm³, cm³/s, °C, s.

    dV/dt   = F_H + F_C + F_D − F(h)
    V·dT/dt = F_H·T_H + F_C·T_C + F_D·T_D − (F_H + F_C + F_D)·T
    F(h) = α·√h,   V = C·h²,   T_out(t) = T(t − τ),   F_C(t) = F_Cin(t − τ_C)

Outputs ``h`` [cm], ``T_out`` [°C]; inputs ``F_H``, ``F_Cin`` [cm³/s]; disturbances ``F_D``
[cm³/s], ``T_D``, ``T_H``, ``T_C`` [°C]. RK4 with exact delays; physics guards (clipped flows,
overflow, empty tank) counted in ``status``: docs/plants.md ("Mixing tank").
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from math import sqrt
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from tank_control.core.scipy_lazy import expm

from tank_control.core.interfaces import NS_PER_S, StatusValue, seconds
from tank_control.core.params import check_config, config_from, param
from tank_control.core.plants.delay_line import DelayLine, HermiteDelayLine
from tank_control.core.plants.siso import StepLength, as_floats

T_MIN, T_MAX = 0.0, 100.0
"""Physical range of the inflow temperatures [°C] (liquid water)."""
FLOW_MAX = 1e6
"""Largest flow [cm³/s] the tank takes (the bound of its flow parameters): a larger inflow is
clipped to it and counted, so the volume and temperature stay finite."""

_MAX_SUBSTEPS = 64          # sub-steps of one RK4 step near an empty tank
MAX_STEPS_PER_TICK = 5e4
"""Largest ``sample_time / integration_step``: RK4 steps of one tick (≈ 10 µs each, so at
most about half a second of CPU per tick; 1e-6 s steps in a 1 s tick stalled a lockstep loop
for minutes)."""


def tick_reason(config: Any, sample_time: float) -> str | None:
    """The RK4 steps one tick of ``sample_time`` [s] needs stay within MAX_STEPS_PER_TICK."""
    if sample_time / config.integration_step > MAX_STEPS_PER_TICK * (1.0 + 1e-9):   # rounding
        return (f'integration_step: {config.integration_step:g} s makes a tick of sample_time '
                f'{sample_time:g} s {sample_time / config.integration_step:.3g} RK4 steps; '
                f'allowed at least sample_time/{MAX_STEPS_PER_TICK:g} = '
                f'{sample_time / MAX_STEPS_PER_TICK:g} s')
    return None
_RK4_STABLE = 2.5           # |λ·δ| below which RK4 is used (its stability limit is 2.78)


@dataclass(frozen=True)
class TankOperatingPoint:
    """Operating point and constants of the mixing tank ([Michalski2021] §1, [Michalski2021] §1).

    The equilibrium level and temperature follow from the inflows:
    ``h = ((F_H + F_C + F_D)/alpha)²`` [cm] and
    ``T = (F_H·T_H + F_C·T_C + F_D·T_D)/(F_H + F_C + F_D)`` [°C].
    Defaults are the document's point: h = 81 cm, T = 2115/63 = 33.5714 °C.
    """

    F_H: float = 14.0      # hot inflow [cm³/s]
    F_C: float = 37.0      # cold inflow (= F_Cin in steady state) [cm³/s]
    F_D: float = 12.0      # disturbance inflow [cm³/s]
    T_H: float = 62.0      # [°C]
    T_C: float = 23.0      # [°C]
    T_D: float = 33.0      # [°C]
    C: float = 0.7         # V = C·h² [cm]
    alpha: float = 7.0     # F = alpha·√h [cm^2.5/s]
    tau: float = 120.0     # output dead time on T_out [s]
    tau_c: float = 180.0   # input dead time on F_Cin [s]

    @property
    def inflow(self) -> float:
        """Total inflow = outflow at equilibrium [cm³/s]."""
        return self.F_H + self.F_C + self.F_D

    @property
    def h(self) -> float:
        """Equilibrium level [cm] (F(h) = alpha·√h = inflow)."""
        return (self.inflow / self.alpha) ** 2

    @property
    def V(self) -> float:
        """Equilibrium volume [cm³] (V = C·h²)."""
        return self.C * self.h ** 2

    @property
    def T(self) -> float:
        """Equilibrium (mixed) temperature [°C]."""
        return (self.F_H * self.T_H + self.F_C * self.T_C + self.F_D * self.T_D) / self.inflow


OPERATING_POINT = TankOperatingPoint()
"""[Michalski2021]'s operating point: F_H 14, F_C 37, F_D 12 cm³/s; T_H 62, T_C 23, T_D 33 °C; h 81 cm."""
_OP = OPERATING_POINT


@dataclass(frozen=True)
class MixingTankConfig:
    """Parameters of ``MixingTank``; defaults are [Michalski2021]'s constants and operating point."""

    C: float = param(_OP.C, 'volume constant C in V = C·h²', unit='cm', min=1e-6, max=1e6,
                     source='[Michalski2021] §1')
    alpha: float = param(_OP.alpha, 'outflow constant α in F(h) = α·√h', unit='cm^2.5/s',
                         min=0.0, max=1e6, source='[Michalski2021] §1')
    F_H: float = param(_OP.F_H, 'operating point: hot inflow F_H', unit='cm³/s', min=0.0,
                       max=1e6, source='[Michalski2021] §1')
    F_C: float = param(_OP.F_C, 'operating point: cold inflow F_C; also fills the τ_C delay '
                       'line at reset', unit='cm³/s', min=0.0, max=1e6, source='[Michalski2021] §1')
    F_D: float = param(_OP.F_D, 'operating point: disturbance inflow F_D', unit='cm³/s',
                       min=0.0, max=1e6, source='[Michalski2021] §1')
    T_H: float = param(_OP.T_H, 'operating point: hot water temperature T_H', unit='°C',
                       min=T_MIN, max=T_MAX)
    T_C: float = param(_OP.T_C, 'operating point: cold water temperature T_C', unit='°C',
                       min=T_MIN, max=T_MAX)
    T_D: float = param(_OP.T_D, 'operating point: disturbance temperature T_D', unit='°C',
                       min=T_MIN, max=T_MAX)
    h_op: float = param(_OP.h, 'operating point: level h for linearize', unit='cm', min=1e-6,
                        max=1e6, source='[Michalski2021] §1')
    T_op: float = param(33.57, 'operating point: temperature T for linearize ([Michalski2021] §1 prints '
                        '33.57; the exact steady state is 2115/63 = 33.5714)', unit='°C',
                        min=T_MIN, max=T_MAX)
    tau_cold: float = param(_OP.tau_c, 'transport delay τ_C from F_Cin to F_C', unit='s',
                            min=0.0, max=1e4, source='[Michalski2021] §1')
    tau_out: float = param(_OP.tau, 'transport delay τ from T to T_out', unit='s', min=0.0,
                           max=1e4, source='[Michalski2021] §1')
    h_max: float = param(200.0, 'overflow height: above it the tank spills (not in [Michalski2021])',
                         unit='cm', min=1e-6, max=1e6)
    integration_step: float = param(0.1, 'RK4 step inside each sample', unit='s', min=1e-6,
                                    max=1e3)
    initial_h: float = param(_OP.h, 'level at reset', unit='cm', min=0.0, max=1e6)
    initial_T: float = param(_OP.T, 'temperature at reset and before t = 0 (T_out history); '
                             'default: the steady state 2115/63 of the operating point',
                             unit='°C', min=T_MIN, max=T_MAX)
    max_dead_time: float = param(600.0, 'history kept by the delay lines; the largest '
                                 'tau_cold and tau_out allowed', unit='s', min=0.0, max=1e4,
                                 read_only=True)

    def reason(self) -> str | None:
        for name in ('tau_cold', 'tau_out'):
            value = getattr(self, name)
            if value > self.max_dead_time:
                return (f'{name}: {value:g} is above max_dead_time; '
                        f'allowed [0, {self.max_dead_time:g}]')
        if self.initial_h > self.h_max:
            return f'initial_h: {self.initial_h:g} is above h_max; allowed [0, {self.h_max:g}]'
        return None


class _Inflow(NamedTuple):
    """Inflows held over one RK4 piece: total flow [cm³/s], heat flow Q = Σ F·T, temperatures."""

    total: float
    heat: float
    t_low: float
    t_high: float


def _inflow(flows: tuple[float, float, float], temps: tuple[float, float, float]) -> _Inflow:
    """Total flow, heat flow and the range of the temperatures of the flows present (> 0)."""
    (f_1, f_2, f_3), (t_1, t_2, t_3) = flows, temps
    t_low, t_high = math.inf, -math.inf
    if f_1 > 0.0:           # the flows in order, each: min and max of the temperatures
        if t_1 < t_low:
            t_low = t_1
        if t_1 > t_high:
            t_high = t_1
    if f_2 > 0.0:
        if t_2 < t_low:
            t_low = t_2
        if t_2 > t_high:
            t_high = t_2
    if f_3 > 0.0:
        if t_3 < t_low:
            t_low = t_3
        if t_3 > t_high:
            t_high = t_3
    return _Inflow(sum(flows), sum((f_1 * t_1, f_2 * t_2, f_3 * t_3)), t_low, t_high)


def jacobian(cfg: Any) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time (A, B) of [Michalski2021] §1 at the operating point of ``cfg`` (any object with
    ``C, alpha, F_H, F_C, F_D, T_H, T_C, T_D, h_op, T_op``), derived analytically with
    x = [V, T] (cm³, °C), u = [F_H, F_C, F_D, T_H, T_C, T_D] (cm³/s, °C).

    ∂(dV/dt)/∂V = −F(h)/(4V) since F = α·(V/C)^(1/4); ∂(dT/dt)/∂V = −(Q − F_in·T)/V²;
    ∂(dT/dt)/∂T = −F_in/V; ∂(dT/dt)/∂F_i = (T_i − T)/V; ∂(dT/dt)/∂T_i = F_i/V.
    """
    V = cfg.C * cfg.h_op ** 2
    T = cfg.T_op
    flows = (cfg.F_H, cfg.F_C, cfg.F_D)
    temps = (cfg.T_H, cfg.T_C, cfg.T_D)
    f_in = sum(flows)
    heat = sum(f * t for f, t in zip(flows, temps))
    outflow = cfg.alpha * math.sqrt(math.sqrt(V / cfg.C))        # F(h_op) = α·√h_op
    a = np.array([[-outflow / (4.0 * V), 0.0],
                  [-(heat - f_in * T) / V ** 2, -f_in / V]])
    b = np.zeros((2, 6))
    b[0, :3] = 1.0
    b[1, :3] = [(t - T) / V for t in temps]
    b[1, 3:] = [f / V for f in flows]
    return a, b


class MixingTank:
    """The nonlinear mixing tank of [Michalski2021] §1 with delays on F_Cin (τ_C) and T_out (τ).

    Inside every ``step`` the state (V, T) is integrated with fixed-step RK4
    (``integration_step``). The delayed cold inflow F_C is piecewise constant (exact
    ``DelayLine``) and the RK4 grid is split at its switch instants, so a τ_C that is not a
    multiple of the sample time costs no accuracy. T is stored on the RK4 grid with its
    one-sided slopes in a ``HermiteDelayLine``: T_out is exact at grid instants and
    fourth-order accurate between them. Near an empty tank (stiff T equation, rate F_in/V)
    RK4 is sub-stepped, and where even that is unstable T follows the exact solution for
    frozen V.
    """

    output_names: tuple[str, ...] = ('h', 'T_out')
    input_names: tuple[str, ...] = ('F_H', 'F_Cin')
    disturbance_names: tuple[str, ...] = ('F_D', 'T_D', 'T_H', 'T_C')
    def __init__(self, config: MixingTankConfig | None = None) -> None:
        self._set_config(check_config(config if config is not None else MixingTankConfig()))
        self._cold = DelayLine(self._config.max_dead_time, initial=self._config.F_C)
        self._temperature = HermiteDelayLine(self._config.max_dead_time)
        self._dt = StepLength()
        self.reset()

    def _set_config(self, cfg: MixingTankConfig) -> None:
        """Take ``cfg`` into use, with the constants of the right-hand side: α, C and the
        brim volume C·h_max² [cm³]."""
        self._config = cfg
        self._alpha, self._c = cfg.alpha, cfg.C
        self._v_brim = cfg.C * cfg.h_max ** 2
        self._end_rhs: tuple[float, float, _Inflow, tuple[float, float, float]] | None = None

    # ---- configuration -------------------------------------------------------------
    @property
    def config(self) -> MixingTankConfig:
        """The current configuration (change it with ``configure``)."""
        return self._config

    def configure(self, **changes: Any) -> None:
        """Change parameters live (all-or-nothing), effective from the next ``step``.

        The state (V, T) is kept: a change of ``C`` keeps the volume (the level
        output changes). ``initial_h``, ``initial_T`` and ``F_C`` (the pre-fill of
        the τ_C line) act at the next ``reset``; the operating point also sets
        ``linearize`` and ``nominal_*``. ``max_dead_time`` is read-only.
        Raises ``ValueError`` with a one-line reason.
        """
        self._set_config(config_from(MixingTankConfig, changes, self._config, live=True))

    # ---- Plant protocol ------------------------------------------------------------
    def reset(self) -> None:
        """Initial state (initial_h, initial_T); delay lines pre-filled (F_C, initial_T)."""
        cfg = self._config
        self._V = cfg.C * cfg.initial_h ** 2
        self._T = cfg.initial_T
        self._t_ns = 0
        self._cold.reset(cfg.F_C)
        self._temperature.reset(cfg.initial_T, 0.0)
        self._F_C = cfg.F_C
        self._counts = {key: 0 for key in (
            'steps', 'clipped_F_H', 'clipped_F_Cin', 'clipped_F_D', 'clipped_T_D',
            'clipped_T_H', 'clipped_T_C', 'overflow_steps', 'empty_steps', 'stiff_substeps')}
        self._spilled = 0.0
        self._overflow = False
        self._empty = False
        self._end_rhs = None

    @property
    def time(self) -> float:
        """Plant time [s] since ``reset``."""
        return seconds(self._t_ns)

    @property
    def state(self) -> np.ndarray:
        """``[V, T]``: volume [cm³] and (undelayed) tank temperature [°C]."""
        return np.array([self._V, self._T])

    def level(self) -> float:
        """h = √(V/C) [cm]."""
        return math.sqrt(max(self._V, 0.0) / self._config.C)

    def outputs(self) -> np.ndarray:
        """``[h, T_out]`` now, with T_out(t) = T(t − τ) (noise-free)."""
        cfg = self._config
        t_out = self._temperature.delayed(self._t_ns / NS_PER_S, cfg.tau_out)   # seconds(t_ns)
        V = self._V
        return np.array([sqrt((0.0 if V < 0.0 else V) / cfg.C), t_out])        # level()

    def nominal_inputs(self) -> np.ndarray:
        """``[F_H, F_Cin]`` of the operating point [cm³/s]."""
        return np.array([self._config.F_H, self._config.F_C])

    def nominal_disturbances(self) -> np.ndarray:
        """``[F_D, T_D, T_H, T_C]`` of the operating point (also used when ``d`` is empty)."""
        cfg = self._config
        return np.array([cfg.F_D, cfg.T_D, cfg.T_H, cfg.T_C])

    def step(self, u: Any, d: Any, dt: float) -> None:
        """Advance ``dt`` seconds with inputs and disturbances held (ZOH).

        ``u = [F_H, F_Cin]``, ``d = [F_D, T_D, T_H, T_C]`` (empty ``d`` = operating
        point). Raises ``ValueError`` (state untouched) on a wrong size,
        non-finite value or bad ``dt``; out-of-range physical values are clipped
        and counted instead.
        """
        u_vec = as_floats('u', u, 2)
        d_vec = as_floats('d', d, 4, allow_empty=True)
        if not d_vec:
            d_vec = self.nominal_disturbances().tolist()
        dt_ns = self._dt.ns(dt)
        f_hot, f_cold_in = u_vec
        f_dist, t_dist, t_hot, t_cold = d_vec
        if not (0.0 <= f_hot <= FLOW_MAX and 0.0 <= f_cold_in <= FLOW_MAX
                and 0.0 <= f_dist <= FLOW_MAX and T_MIN <= t_dist <= T_MAX
                and T_MIN <= t_hot <= T_MAX and T_MIN <= t_cold <= T_MAX):
            f_hot = self._clip('F_H', f_hot, 0.0, FLOW_MAX)
            f_cold_in = self._clip('F_Cin', f_cold_in, 0.0, FLOW_MAX)
            f_dist = self._clip('F_D', f_dist, 0.0, FLOW_MAX)
            t_dist = self._clip('T_D', t_dist, T_MIN, T_MAX)
            t_hot = self._clip('T_H', t_hot, T_MIN, T_MAX)
            t_cold = self._clip('T_C', t_cold, T_MIN, T_MAX)

        cfg = self._config
        t_ns = self._t_ns
        self._cold.push(t_ns, f_cold_in)
        self._overflow = False
        t_start, span = t_ns / NS_PER_S, dt_ns / NS_PER_S        # seconds(...)
        t_end = (t_ns + dt_ns) / NS_PER_S
        offset = 0.0
        pieces = self._cold.segments(t_ns, span, cfg.tau_cold)
        last_piece = len(pieces) - 1
        advance = self._advance
        integration_step = cfg.integration_step
        for index, (duration, f_cold) in enumerate(pieces):
            if duration <= 0.0:
                continue
            inflow = _inflow((f_hot, f_cold, f_dist), (t_hot, t_cold, t_dist))
            n = math.ceil(duration / integration_step - 1e-9)
            if n < 1:           # max(1, n)
                n = 1
            h = duration / n
            for j in range(1, n):                       # grid instants inside the piece
                advance(inflow, h, t_start + offset + j * h)
            # the piece's last step ends at t_end if it is the step's last piece
            advance(inflow, h, t_end if index == last_piece else t_start + offset + n * h)
            offset += duration
            self._F_C = f_cold
        self._empty = self._V <= 0.0
        counts = self._counts
        counts['overflow_steps'] += self._overflow
        counts['empty_steps'] += self._empty
        counts['steps'] += 1
        self._t_ns = t_ns + dt_ns

    @property
    def status(self) -> Mapping[str, StatusValue]:
        """Counters and flags of the physics guards (docs/plants.md).

        ``clipped_<channel>``: steps in which that input was clipped;
        ``clipped_flows``: their sum over F_H, F_Cin, F_D; ``overflow``: spilled in
        the last step; ``overflow_steps``; ``spilled_volume`` [cm³]; ``empty``:
        level 0 after the last step; ``empty_steps``; ``stiff_substeps``: RK4
        steps sub-divided near an empty tank; ``time`` [s]; ``steps``; the state
        ``V`` [cm³], ``T`` [°C], ``h`` [cm]; ``F_C`` delayed cold inflow now
        entering [cm³/s]; ``F_out`` outflow α·√h [cm³/s].
        """
        status: dict[str, StatusValue] = dict(self._counts)
        status['clipped_flows'] = sum(self._counts[f'clipped_{k}'] for k in ('F_H', 'F_Cin', 'F_D'))
        status.update(time=self.time, overflow=self._overflow, spilled_volume=self._spilled,
                      empty=self._empty, V=self._V, T=self._T, h=self.level(),
                      F_C=self._F_C, F_out=self._outflow(self._V))
        return status

    # ---- linear model --------------------------------------------------------------
    def jacobian(self) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time (A, B) at this tank's operating point: :func:`jacobian`."""
        return jacobian(self._config)

    def linearize(self, ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Discrete (A, B, C, D) at the operating point, sampling ``ts`` [s] ([Michalski2021] eqs. 4–6).

        x = [V, T] (V in cm³), u = [F_H, F_C, F_D, T_H, T_C, T_D], y = x (C = I, D = 0).
        Exact zero-order-hold discretisation: expm of the augmented matrix
        [[A, B], [0, 0]]·ts. The delays τ_C and τ are NOT included (as in [Michalski2021]);
        the model is in absolute variables up to a constant term ([Michalski2021]'s k_const).
        """
        if not (math.isfinite(ts) and ts > 0.0):
            raise ValueError(f'ts: {ts!r} must be a finite number of seconds > 0')
        a, b = self.jacobian()
        augmented = np.zeros((8, 8))
        augmented[:2, :2] = a
        augmented[:2, 2:] = b
        phi = expm(augmented * ts)
        return phi[:2, :2], phi[:2, 2:], np.eye(2), np.zeros((2, 6))

    # ---- integration ---------------------------------------------------------------
    def _clip(self, name: str, value: float, low: float, high: float) -> float:
        if low <= value <= high:
            return float(value)
        clipped = min(max(float(value), low), high)
        if clipped != value:
            self._counts[f'clipped_{name}'] += 1
        return clipped

    def _outflow(self, V: float) -> float:
        """F(h) = α·√h with h = √(V/C): α·(V/C)^(1/4) [cm³/s]; 0 for an empty tank."""
        return self._alpha * math.sqrt(math.sqrt(max(V, 0.0) / self._c))

    def _rhs(self, V: float, T: float, total: float, heat: float
             ) -> tuple[float, float, float]:
        """(dV/dt, dT/dt, spill rate) with the inflow ``total`` [cm³/s] and heat flow ``heat``
        (:class:`_Inflow`): [Michalski2021] §1, with the level pinned at the brim h_max while the net
        inflow is positive (the excess spills)."""
        # _outflow(V); ``0.0 if V < 0.0 else V`` is max(V, 0.0) without the call
        dV = total - self._alpha * sqrt(sqrt((0.0 if V < 0.0 else V) / self._c))
        dT = (heat - total * T) / V if V > 0.0 else 0.0
        if dV > 0.0 and V >= self._v_brim:
            return 0.0, dT, dV
        return dV, dT, 0.0

    def _stiffness(self, V: float, inflow: _Inflow) -> float:
        """Largest rate [1/s] of the local dynamics: F_in/V (T) and F(h)/(4V) (V)."""
        if V <= 0.0:
            return math.inf
        return (inflow.total + 0.25 * self._outflow(V)) / V

    def _advance(self, inflow: _Inflow, h: float, t_b: float) -> None:
        """One RK4 step of length ``h`` ending at grid instant ``t_b``; records T there."""
        V0, T0 = self._V, self._T
        total, heat, t_low, t_high = inflow
        if V0 <= 0.0:       # _stiffness(V0, inflow), written out
            rate = math.inf
        else:               # _outflow(V0): max(V0, 0.0) is V0 here (also a NaN)
            rate = (total + 0.25 * (self._alpha * sqrt(sqrt(V0 / self._c)))) / V0
        exact_t = False
        if rate * h <= 1.0:     # one RK4 step (rate·h ≤ 1 is within RK4's stability limit)
            last = self._end_rhs    # the right-hand side where the previous step ended
            if last is not None and last[2] is inflow and last[0] == V0 and last[1] == T0:
                start = last[3]
            else:
                start = self._rhs(V0, T0, total, heat)
            V, T = self._rk4(V0, T0, total, heat, h, start)
            if not 0.0 <= V <= self._v_brim:     # (else the guard changes nothing)
                V = self._guard_volume(V)
        else:
            substeps = _MAX_SUBSTEPS if rate * h >= _MAX_SUBSTEPS else math.ceil(rate * h)
            self._counts['stiff_substeps'] += 1
            delta = h / substeps
            V, T = V0, T0
            start = None    # the right-hand side at (V0, T0), if the first sub-step has it
            for i in range(substeps):
                # the first sub-step starts at V0: its stiffness is ``rate``
                if (rate if i == 0 else self._stiffness(V, inflow)) * delta <= _RK4_STABLE:
                    k1 = self._rhs(V, T, total, heat)
                    if i == 0:
                        start = k1
                    V, T = self._rk4(V, T, total, heat, delta, k1)
                else:
                    V, T = self._frozen_volume_step(V, T, inflow, delta)
                    exact_t = True
                V = self._guard_volume(V)
        # T within [min(T0, t_low), max(T0, t_high)]: min/max written out (same results:
        # max(a, b) is ``b if b > a else a``, min(a, b) is ``b if b < a else a``)
        low = t_low if t_low < T0 else T0
        high = t_high if t_high > T0 else T0
        if low > T:
            T = low
        if high < T:
            T = high
        self._V, self._T = V, T
        if exact_t:     # slopes meaningless across a stiff transient: interpolate linearly
            slope_a = slope_b = (T - T0) / h
            self._end_rhs = None
        else:
            slope_a = (start or self._rhs(V0, T0, total, heat))[1]
            end = self._rhs(V, T, total, heat)
            slope_b = end[1]
            self._end_rhs = (V, T, inflow, end)
        self._temperature.extend(t_b, T, slope_a, slope_b)

    def _rk4(self, V: float, T: float, total: float, heat: float, h: float,
             k1: tuple[float, float, float] | None = None) -> tuple[float, float]:
        """One classical RK4 step of length ``h`` with the inflow ``total`` and heat flow
        ``heat`` (``k1``: the right-hand side at (V, T) if already known).

        The stages k2, k3, k4 are :meth:`_rhs` written out, the same operations in the same
        order (three calls were a fifth of a tank tick); :func:`rk4_reference` in
        test_plants_mixing_tank.py checks this against RK4 over ``_rhs`` bit for bit.
        """
        dV1, dT1, s1 = k1 or self._rhs(V, T, total, heat)
        alpha, c, v_brim = self._alpha, self._c, self._v_brim
        half = 0.5 * h          # 0.5·h·k is (0.5·h)·k
        V2, T2 = V + half * dV1, T + half * dT1
        dV2 = total - alpha * sqrt(sqrt((0.0 if V2 < 0.0 else V2) / c))    # _rhs(V2, T2)
        dT2 = (heat - total * T2) / V2 if V2 > 0.0 else 0.0
        s2 = 0.0
        if dV2 > 0.0 and V2 >= v_brim:
            dV2, s2 = 0.0, dV2
        V3, T3 = V + half * dV2, T + half * dT2
        dV3 = total - alpha * sqrt(sqrt((0.0 if V3 < 0.0 else V3) / c))    # _rhs(V3, T3)
        dT3 = (heat - total * T3) / V3 if V3 > 0.0 else 0.0
        s3 = 0.0
        if dV3 > 0.0 and V3 >= v_brim:
            dV3, s3 = 0.0, dV3
        V4, T4 = V + h * dV3, T + h * dT3
        dV4 = total - alpha * sqrt(sqrt((0.0 if V4 < 0.0 else V4) / c))    # _rhs(V4, T4)
        dT4 = (heat - total * T4) / V4 if V4 > 0.0 else 0.0
        s4 = 0.0
        if dV4 > 0.0 and V4 >= v_brim:
            dV4, s4 = 0.0, dV4
        sixth = h / 6.0         # h/6·(…) is (h/6)·(…)
        spill = sixth * (s1 + 2.0 * s2 + 2.0 * s3 + s4)
        if spill > 0.0:
            self._spilled += spill
            self._overflow = True
        return (V + sixth * (dV1 + 2.0 * dV2 + 2.0 * dV3 + dV4),
                T + sixth * (dT1 + 2.0 * dT2 + 2.0 * dT3 + dT4))

    def _frozen_volume_step(self, V: float, T: float, inflow: _Inflow,
                            h: float) -> tuple[float, float]:
        """Stable step for a nearly empty tank: RK4 on V alone, T exact for frozen V."""
        k1 = inflow.total - self._outflow(V)
        k2 = inflow.total - self._outflow(V + 0.5 * h * k1)
        k3 = inflow.total - self._outflow(V + 0.5 * h * k2)
        k4 = inflow.total - self._outflow(V + h * k3)
        V_new = max(V + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4), 0.0)
        if inflow.total > 0.0:
            mix = inflow.heat / inflow.total
            V_mean = 0.5 * (V + V_new)
            decay = math.exp(-inflow.total * h / V_mean) if V_mean > 0.0 else 0.0
            T = mix + (T - mix) * decay
        return V_new, T

    def _guard_volume(self, V: float) -> float:
        """Level ≥ 0; above h_max the excess spills (counted in ``spilled_volume``)."""
        if V < 0.0:
            return 0.0
        V_max = self._v_brim
        if V > V_max:
            self._spilled += V - V_max
            self._overflow = True
            return V_max
        return V
