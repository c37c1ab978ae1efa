"""make_plant / plant_params: the parameter interface of the plant models."""
from __future__ import annotations

import pytest

from tank_control.core.interfaces import Plant
from tank_control.core.plants import PLANT_KINDS, make_plant, plant_params

EXPECTED = {
    'ipdt': {'gain', 'dead_time', 'initial_output', 'max_dead_time'},
    'fopdt': {'gain', 'dead_time', 'time_constant', 'initial_output', 'max_dead_time'},
    'mixing_tank': {'C', 'alpha', 'F_H', 'F_C', 'F_D', 'T_H', 'T_C', 'T_D', 'h_op', 'T_op',
                    'tau_cold', 'tau_out', 'h_max', 'integration_step', 'initial_h',
                    'initial_T', 'max_dead_time'},
}


@pytest.mark.parametrize('kind', PLANT_KINDS)
def test_every_parameter_is_described_and_its_default_accepted(kind):
    specs = plant_params(kind)
    assert {s.name for s in specs} == EXPECTED[kind]
    for spec in specs:
        assert spec.description and '[' in spec.description, spec.name   # units given
        assert spec.check(spec.default) is None
    plant = make_plant(kind, {})
    assert isinstance(plant, Plant)
    assert {s.name for s in specs} == set(vars(plant.config))


def test_defaults_are_the_documents_examples():
    ipdt, fopdt, tank = (make_plant(k, {}).config for k in PLANT_KINDS)
    assert (ipdt.gain, ipdt.dead_time) == (0.05, 5.0)                 # 000
    assert (fopdt.gain, fopdt.time_constant, fopdt.dead_time) == (0.05, 10.0, 3.0)   # 001
    assert (tank.C, tank.alpha, tank.tau_cold, tank.tau_out) == (0.7, 7.0, 180.0, 120.0)  # 003
    assert (tank.F_H, tank.F_C, tank.F_D, tank.T_H, tank.T_C, tank.T_D) == (14, 37, 12, 62, 23, 33)


def test_values_are_applied_and_ints_accepted_for_floats():
    plant = make_plant('fopdt', {'gain': 2, 'dead_time': 1.5})
    assert plant.config.gain == 2.0 and isinstance(plant.config.gain, float)
    assert plant.config.dead_time == 1.5


def test_unknown_kind_names_it_and_lists_the_choices():
    with pytest.raises(ValueError, match="'sotd' is not a plant kind.*ipdt, fopdt, mixing_tank"):
        make_plant('sotd', {})
    with pytest.raises(ValueError, match='ipdt, fopdt, mixing_tank'):
        plant_params('SOTD')


@pytest.mark.parametrize('kind, values, words', [
    ('ipdt', {'dead_time': 500.0}, 'dead_time: 500 is above max_dead_time'),
    ('fopdt', {'time_constant': -1}, 'time_constant: -1 is below the minimum'),
    ('fopdt', {'noise_std': 0.1}, 'noise_std: unknown parameter'),
    ('mixing_tank', {'tau_out': float('inf')}, 'tau_out: inf is not finite'),
    ('mixing_tank', {'h_max': 'high'}, "h_max: 'high' is a str"),
])
def test_bad_values_are_rejected_with_a_reason(kind, values, words):
    with pytest.raises(ValueError, match=words):
        make_plant(kind, values)


@pytest.mark.parametrize('kind', PLANT_KINDS)
def test_every_plant_changes_live_through_configure(kind):
    plant = make_plant(kind, {})
    name = 'dead_time' if kind != 'mixing_tank' else 'tau_out'
    plant.configure(**{name: 2.5})
    assert getattr(plant.config, name) == 2.5
    with pytest.raises(ValueError, match='max_dead_time: read-only'):
        plant.configure(max_dead_time=1.0)
