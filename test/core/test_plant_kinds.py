"""The plant kinds (``core/plants/kinds``): parameters declared once and built (the contract,
live changes included: test_kind_contract.py)."""
from __future__ import annotations

import dataclasses

import pytest

from tank_control.core.interfaces import Plant
from tank_control.core.params import ConfigError
from tank_control.core.plants.kinds.registry import BUILT_IN, KINDS, get_kind, make_plant


@pytest.mark.parametrize('kind', KINDS)
def test_every_parameter_is_a_described_config_field_with_an_accepted_default(kind):
    plant_kind = get_kind(kind)
    specs = plant_kind.specs()
    assert {s.name for s in specs} == {f.name for f in dataclasses.fields(plant_kind.config)}
    for spec in specs:
        assert spec.description and spec.check(spec.default) is None, spec.name
    plant = make_plant(kind)
    assert isinstance(plant, Plant)
    assert plant.config == plant_kind.config()


def test_defaults_are_the_documents_examples():
    ipdt, fopdt, tank = (make_plant(k).config for k in ('ipdt', 'fopdt', 'mixing_tank'))
    assert (ipdt.gain, ipdt.dead_time) == (0.05, 5.0)                 # [Viteckova]
    assert (fopdt.gain, fopdt.time_constant, fopdt.dead_time) == (0.05, 10.0, 3.0)   # [DeadTimeNotes]
    assert (tank.C, tank.alpha, tank.tau_cold, tank.tau_out) == (0.7, 7.0, 180.0, 120.0)  # [Michalski2021]
    assert (tank.F_H, tank.F_C, tank.F_D, tank.T_H, tank.T_C, tank.T_D) == (14, 37, 12, 62, 23, 33)
    assert (tank.initial_h, tank.initial_T) == (81.0, 2115.0 / 63.0)   # its steady state


def test_values_are_applied_and_ints_accepted_for_floats():
    plant = make_plant('fopdt', {'gain': 2, 'dead_time': 1.5})
    assert plant.config.gain == 2.0 and isinstance(plant.config.gain, float)
    assert plant.config.dead_time == 1.5


def test_an_unknown_kind_is_refused_with_the_nearest_name():
    with pytest.raises(ConfigError, match="plant: fopd: unknown plant kind; did you mean fopdt"):
        make_plant('fopd')


@pytest.mark.parametrize('kind, values, words', [
    ('ipdt', {'dead_time': 500.0}, 'dead_time: 500 is above max_dead_time'),
    ('fopdt', {'time_constant': -1}, 'time_constant: -1 is below the minimum'),
    ('fopdt', {'noise_std': 0.1}, 'noise_std: unknown parameter'),
    ('fopdt', {'dead_tme': 3.0}, 'dead_tme: unknown parameter; did you mean dead_time'),
    ('mixing_tank', {'tau_out': float('inf')}, 'tau_out: inf is not finite'),
    ('mixing_tank', {'h_max': 'high'}, "h_max: 'high' is a str"),
])
def test_bad_values_are_rejected_with_a_reason(kind, values, words):
    with pytest.raises(ValueError, match=words):
        make_plant(kind, values)


def test_every_plant_kind_module_is_in_the_table():
    import pkgutil

    import tank_control.core.plants.kinds as package
    modules = {m.name for m in pkgutil.iter_modules(package.__path__)} - {'base', 'registry'}
    assert modules == set(BUILT_IN)
