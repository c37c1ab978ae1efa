"""Actuator faults (core/plants/actuator.py): the input/output shapes of Choudhury's two-parameter
stiction model [Choudhury2005] (its Fig. of the model's response to a sinusoid: pure deadband
J = 0, undershoot S > J, no offset S = J, overshoot J > S), backlash, rate limit, and the
parameters as every plant kind takes them."""
from __future__ import annotations

import numpy as np
import pytest

from tank_control.core import scenario
from tank_control.core.params import ConfigError
from tank_control.core.plants.actuator import ActuatedPlant, ActuatorChain, ActuatorConfig
from tank_control.core.plants.kinds import registry

DT = 0.1


def respond(u: np.ndarray, **fields: float) -> np.ndarray:
    chain = ActuatorChain(ActuatorConfig(**{k: (v,) for k, v in fields.items()}), ('u',))
    return np.array([chain.apply(np.array([v]), DT)[0] for v in u])


def sine(amplitude: float = 10.0, period: float = 100.0, cycles: float = 2.0) -> np.ndarray:
    t = np.arange(0.0, cycles * period, DT)
    return amplitude * np.sin(2 * np.pi * t / period)


def moving_offsets(u: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """x − u where the valve moves, split by the input's direction (rising, falling)."""
    du, dx = np.diff(u), np.diff(x)
    moving = np.abs(dx) > 0
    off = (x - u)[1:]
    return off[moving & (du > 0)], off[moving & (du < 0)]


@pytest.mark.parametrize('s, j', [(5.0, 0.0), (5.0, 2.0), (5.0, 5.0), (5.0, 7.0)])
def test_sine_response_has_the_published_shape(s: float, j: float) -> None:
    """Moving, the valve sits at u − sign(du)·(S − J)/2 (behind the input by (S − J)/2 for
    S > J, on it for S = J, ahead by (J − S)/2 for J > S); after each reversal of the input it
    stays flat until the input has come back by S, then jumps by J."""
    u = sine()
    x = respond(u, stiction_s=s, stiction_j=j)
    rising, falling = moving_offsets(u, x)
    # every step where the valve moves (past the first slip of the first cycle)
    assert rising.size > 100 and falling.size > 100
    np.testing.assert_allclose(rising[rising.size // 4:], -(s - j) / 2, atol=1e-9)
    np.testing.assert_allclose(falling, (s - j) / 2, atol=1e-9)
    # the jumps after the first reversal (t = 25 s; the first slip starts from rest at the
    # input): the largest move of the valve is J plus at most one step of the input
    du_max = np.max(np.abs(np.diff(u)))
    jumps = np.abs(np.diff(x[int(25 / DT):]))
    assert jumps.max() <= j + du_max + 1e-9
    if j > 0:
        assert jumps.max() >= j - 1e-9
    # the flat stretch after the input's maximum (t = 25 s): until u has fallen by S
    k_top = int(np.argmax(u[:int(100 / DT)]))
    after = np.arange(k_top, k_top + int(50 / DT))
    first_move = after[np.argmax(np.abs(np.diff(x[after])) > 0)] + 1
    assert u[k_top] - u[first_move] > s
    assert u[k_top] - u[first_move - 1] <= s + 1e-9


def test_small_oscillation_inside_the_band_never_moves_the_valve() -> None:
    """An input whose peak-to-peak stays below S leaves a stuck valve where it is."""
    u = 20.0 + sine(amplitude=2.0)
    x = respond(u, stiction_s=5.0, stiction_j=1.0)
    assert np.all(x == x[0])


def test_a_stop_then_same_direction_needs_only_j() -> None:
    """A ramp paused and resumed in the same direction: the valve sticks at the pause and slips
    once the input has moved J further (not S)."""
    ramp = np.concatenate([np.linspace(0, 10, 101), np.full(20, 10.0), 10 + np.linspace(0, 5, 51)[1:]])
    x = respond(ramp, stiction_s=4.0, stiction_j=1.0)
    resume = 121
    moved = np.flatnonzero(np.abs(np.diff(x[resume - 1:])) > 0)[0] + resume
    assert ramp[moved] - 10.0 > 1.0 and ramp[moved - 1] - 10.0 <= 1.0 + 1e-12


def test_backlash_and_rate_limit() -> None:
    u = sine()
    x = respond(u, deadband=2.0)
    rising, falling = moving_offsets(u, x)
    np.testing.assert_allclose(rising, -1.0, atol=1e-9)
    np.testing.assert_allclose(falling, 1.0, atol=1e-9)
    step = np.concatenate([[0.0], np.full(100, 5.0)])
    y = respond(step, rate_limit=1.0)
    np.testing.assert_allclose(np.diff(y)[:49], 0.1, atol=1e-12)       # 1 unit/s, 0.1 s steps
    assert y[-1] == 5.0


@pytest.mark.parametrize('kind', sorted(registry.KINDS))
def test_every_plant_kind_takes_the_actuator_parameters(kind: str) -> None:
    """The parameters are declared once for all kinds; off by default (the plant unwrapped),
    one value or one per input, a wrong count refused naming the parameter."""
    setup = scenario.plant_setup({'plant': kind})
    assert not isinstance(setup.build_plant(), ActuatedPlant)
    n = len(registry.get_kind(kind).build.input_names)
    setup = scenario.plant_setup({'plant': kind, 'actuator.stiction_s': [3.0] * n,
                                  'actuator.stiction_j': [1.0]})
    plant = setup.build_plant()
    assert isinstance(plant, ActuatedPlant) and plant.input_names == setup.build_plant().input_names
    with pytest.raises(ConfigError, match=r'actuator\.deadband: .* input channels'):
        scenario.plant_setup({'plant': kind, 'actuator.deadband': [1.0] * (n + 1)})
    with pytest.raises(ConfigError, match='actuator.rate_limit'):
        scenario.plant_setup({'plant': kind, 'actuator.rate_limit': [-1.0]})


def test_the_plant_sees_the_valve_position() -> None:
    """In the loop the FOPDT integrates the stuck valve's position, not the command."""
    base = {'plant': 'fopdt', 'gain': 1.0, 'time_constant': 1.0, 'dead_time': 0.0}
    free = scenario.plant_setup(base).build_plant()
    sticky = scenario.plant_setup({**base, 'actuator.stiction_s': [5.0],
                                   'actuator.stiction_j': [1.0]}).build_plant()
    for plant in (free, sticky):
        plant.step(np.array([0.0]), np.array([0.0]), DT)
        for _ in range(100):
            plant.step(np.array([3.0]), np.array([0.0]), DT)     # 3 < S: stays stuck
    assert free.outputs()[0] > 2.9
    assert sticky.outputs()[0] == 0.0
    assert sticky.status['actuator_stuck_steps'] == 100
