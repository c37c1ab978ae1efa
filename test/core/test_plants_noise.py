"""Measurement noise: reproducible by seed, per channel, zero std is exactly no noise."""
from __future__ import annotations

import numpy as np
import pytest

from tank_control.core.params import specs_of
from tank_control.core.plants.noise import MeasurementNoise, NoiseConfig


def test_same_seed_same_noise_and_reset_restarts_the_stream():
    a = MeasurementNoise(2, std=[0.5, 2.0], seed=42)
    b = MeasurementNoise(2, std=[0.5, 2.0], seed=42)
    first = np.array([a.sample() for _ in range(100)])
    np.testing.assert_array_equal(first, [b.sample() for _ in range(100)])
    a.reset()
    np.testing.assert_array_equal(first, [a.sample() for _ in range(100)])
    other = MeasurementNoise(2, std=[0.5, 2.0], seed=43)
    assert not np.array_equal(first, [other.sample() for _ in range(100)])


def test_noise_follows_the_documented_draw_order():
    # One standard_normal(n) per sample instant, scaled per channel.
    noise = MeasurementNoise(3, std=[1.0, 0.0, 3.0], seed=7)
    rng = np.random.default_rng(7)
    for _ in range(5):
        z = rng.standard_normal(3)
        np.testing.assert_array_equal(noise.sample(), [z[0], 0.0, 3.0 * z[2]])


def test_zero_std_adds_exactly_nothing_and_does_not_shift_other_channels():
    y = np.array([81.0, 33.571428571428573])
    quiet = MeasurementNoise(2, std=0.0, seed=1)
    for _ in range(10):
        np.testing.assert_array_equal(quiet.apply(y), y)
    half = MeasurementNoise(2, std=[0.0, 0.1], seed=1)
    both = MeasurementNoise(2, std=[0.2, 0.1], seed=1)
    for _ in range(10):
        assert half.sample()[1] == both.sample()[1]


def test_statistics_match_the_standard_deviation():
    noise = MeasurementNoise(2, std=[0.5, 2.0], seed=3)
    draws = np.array([noise.sample() for _ in range(20000)])
    np.testing.assert_allclose(draws.std(axis=0), [0.5, 2.0], rtol=0.03)
    np.testing.assert_allclose(draws.mean(axis=0), [0.0, 0.0], atol=0.05)


def test_live_std_change_keeps_the_stream():
    a = MeasurementNoise(1, std=1.0, seed=5)
    b = MeasurementNoise(1, std=1.0, seed=5)
    a.sample(), b.sample()
    a.set_std(2.0)
    assert a.sample()[0] == pytest.approx(2.0 * b.sample()[0], rel=1e-15)


@pytest.mark.parametrize('kwargs, words', [
    ({'std': [1.0, 2.0, 3.0]}, 'noise_std: 3 values for 2 output channels'),
    ({'std': -1.0}, 'noise_std'),
    ({'seed': -3}, 'seed'),
    ({'seed': 1.5}, 'seed'),
])
def test_bad_noise_settings_are_rejected(kwargs, words):
    with pytest.raises(ValueError, match=words):
        MeasurementNoise(2, **kwargs)


def test_noise_parameters_are_described():
    names = {spec.name: spec for spec in specs_of(NoiseConfig)}
    assert names['noise_std'].check([0.1, 0.2]) is None
    assert 'below the minimum' in names['noise_std'].check([-0.1])
    assert names['seed'].read_only
