"""Kinds from entry points (issue 32 §1, ``core/kind_plugins.py``): a plugin adds a kind; one
that fails to import, is not a kind, is misnamed or clashes with a taken name is left out
with one line naming the entry point and its distribution, and never hides a built-in."""
from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from importlib.metadata import EntryPoint
from pathlib import Path
from types import SimpleNamespace

import pytest

from tank_control.core import kind_plugins
from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind
from tank_control.core.plants.kinds import registry as plants
from tank_control.core.plants.kinds.base import PlantKind

PID = registry.BUILT_IN['pid']
MODULE = sys.modules[__name__]
MY_KIND = replace(PID, name='my_pid', description='a plugin kind')
PID_AGAIN = replace(PID, description='an impostor')
NOT_A_KIND = object()


class FakeEntryPoint:
    """An entry point of an installed distribution (``ep.dist.name``)."""

    def __init__(self, name: str, value: str, dist: str = 'my-dist'):
        self.name, self.value, self.dist = name, value, SimpleNamespace(name=dist)
        self._real = EntryPoint(name, value, kind_plugins.CONTROLLER_GROUP)

    def load(self):
        return self._real.load()


def load(*eps):
    errors = []
    table = kind_plugins.load(kind_plugins.CONTROLLER_GROUP, registry.BUILT_IN, ControllerKind,
                              'controller kind', found=eps, report=errors.append)
    assert table.errors == errors
    return table


def test_a_plugin_kind_is_added_with_its_distribution():
    table = load(FakeEntryPoint('my_pid', f'{__name__}:MY_KIND'))
    assert table.kinds['my_pid'] is MY_KIND and table.origins['my_pid'] == 'my-dist'
    assert all(table.kinds[n] is k for n, k in registry.BUILT_IN.items())
    assert all(table.origins[n] == 'built-in' for n in registry.BUILT_IN)
    assert table.errors == []


@pytest.mark.parametrize('ep, says', [
    (FakeEntryPoint('broken', 'no_such_module_xyz:KIND', 'broken-dist'),
     "controller kind entry point 'broken' = 'no_such_module_xyz:KIND' (group "
     "tank_control.controller_kinds, distribution broken-dist): cannot be loaded "
     "(ModuleNotFoundError: No module named 'no_such_module_xyz'); left out"),
    (FakeEntryPoint('pid', f'{__name__}:PID_AGAIN', 'clash-dist'),
     f"controller kind entry point 'pid' = '{__name__}:PID_AGAIN' (group "
     "tank_control.controller_kinds, distribution clash-dist): the name 'pid' is taken by the "
     "built-in controller kind; left out"),
    (FakeEntryPoint('thing', f'{__name__}:NOT_A_KIND'),
     'is a object, not a ControllerKind (the value must name the module attribute holding '
     'the kind, e.g. my_pkg.my_kind:KIND); left out'),
    (FakeEntryPoint('other_name', f'{__name__}:MY_KIND'),
     "names the controller kind 'my_pid'; the entry point must be named after it; left out"),
])
def test_a_bad_plugin_is_one_line_and_hides_nothing(ep, says):
    table = load(ep)
    assert len(table.errors) == 1 and '\n' not in table.errors[0]
    assert table.errors[0].endswith(says)
    assert table.kinds == registry.BUILT_IN and table.kinds['pid'] is PID


def test_a_second_plugin_with_a_taken_name_names_the_first_distribution():
    table = load(FakeEntryPoint('my_pid', f'{__name__}:MY_KIND', 'first-dist'),
                 FakeEntryPoint('my_pid', f'{__name__}:MY_KIND', 'second-dist'))
    assert table.origins['my_pid'] == 'first-dist'
    assert table.errors[0].endswith("the name 'my_pid' is taken by the first-dist controller "
                                    'kind; left out')


def test_an_exception_raised_while_importing_a_plugin_is_caught(tmp_path, monkeypatch):
    (tmp_path / 'raising_plugin.py').write_text('raise RuntimeError("boom\\nsecond line")\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    table = kind_plugins.load(kind_plugins.PLANT_GROUP, plants.BUILT_IN, PlantKind, 'plant kind',
                              found=[FakeEntryPoint('x', 'raising_plugin:KIND')],
                              report=lambda line: None)
    assert table.errors[0].endswith('cannot be loaded (RuntimeError: boom); left out')
    assert table.kinds == plants.BUILT_IN


def test_the_registries_use_the_installed_entry_points_in_every_process(tmp_path):
    """A distribution installed as metadata on sys.path (as pip writes it) reaches a new
    process's registries, nodes and CLI alike; its import error is one line on stderr."""
    site = tmp_path / 'site'
    info = site / 'fake_kinds-1.0.dist-info'
    info.mkdir(parents=True)
    (info / 'METADATA').write_text('Metadata-Version: 2.1\nName: fake-kinds\nVersion: 1.0\n')
    (info / 'entry_points.txt').write_text(
        '[tank_control.controller_kinds]\nmy_pid = fake_kinds_mod:KIND\n'
        'broken = fake_kinds_missing:KIND\n')
    (site / 'fake_kinds_mod.py').write_text(
        'from dataclasses import replace\n'
        'from tank_control.core.control.kinds.pid import KIND as PID\n'
        "KIND = replace(PID, name='my_pid', description='from fake-kinds')\n")
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, '-c', 'from tank_control.harness.cli import main; main(["list", '
         '"--kinds"])'], capture_output=True, text=True, timeout=120,
        env={'PYTHONPATH': f'{root}:{site}', 'PATH': '/usr/bin:/bin'})
    assert done.returncode == 0, done.stderr
    line = next(ln for ln in done.stdout.splitlines() if ln.strip().startswith('my_pid'))
    assert line.split()[1] == 'fake-kinds'
    assert "entry point 'broken' = 'fake_kinds_missing:KIND'" in done.stdout    # left out:
    errors = [ln for ln in done.stderr.splitlines() if 'fake_kinds_missing' in ln]
    assert len(errors) == 1 and 'distribution fake-kinds' in errors[0]


def test_a_plant_kind_built_by_a_factory_function_gets_its_channels(monkeypatch):
    """``build`` may be any callable returning a Plant (docs/extending.md), not only its class:
    plant_node's channels and the input ranges come from a model the kind builds."""
    from tank_control.core import node_specs
    ipdt = plants.BUILT_IN['ipdt']
    kind = replace(ipdt, name='factory_ipdt', build=lambda config: ipdt.build(config))
    monkeypatch.setitem(plants.KINDS, 'factory_ipdt', kind)
    assert node_specs.plant_channels('factory_ipdt') == ('u', 'v')
    names = {s.name for s in node_specs.plant_specs('factory_ipdt')}
    assert {'range.u', 'range.v', 'gain'} <= names
