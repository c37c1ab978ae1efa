"""What importing the package costs: core/ never pulls in rclpy (ARCHITECTURE.md), and a node's
start-up does not import the scipy subpackages only tuning and identification call
(``core/scipy_lazy.py``: scipy.optimize and scipy.signal with scipy.stats are ~2 s of CPU)."""
from __future__ import annotations

import json
import pkgutil
import subprocess
import sys

import tank_control.core

HEAVY = ('scipy.optimize', 'scipy.signal', 'scipy.stats', 'scipy.linalg')


def _loaded_after(*modules: str) -> set[str]:
    """Top modules in sys.modules after importing ``modules`` in a fresh interpreter."""
    code = ('import importlib, json, sys\n'
            f'for m in {list(modules)!r}: importlib.import_module(m)\n'
            'print(json.dumps(sorted(sys.modules)))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    return set(json.loads(out.stdout))


def test_core_never_imports_rclpy() -> None:
    core = [m.name for m in pkgutil.walk_packages(tank_control.core.__path__,
                                                  'tank_control.core.')]
    assert len(core) > 50
    loaded = _loaded_after(*core)
    assert not {m for m in loaded if m == 'rclpy' or m.startswith('rclpy.')}


def test_node_start_up_leaves_the_heavy_scipy_parts_for_their_first_use() -> None:
    loaded = _loaded_after('tank_control.nodes.plant_node', 'tank_control.nodes.controller_node',
                           'tank_control.nodes.reference_node')
    assert 'rclpy' in loaded
    assert not {m for m in loaded for heavy in HEAVY if m == heavy or m.startswith(heavy + '.')}


def test_the_lazy_routines_are_scipy_s() -> None:
    import numpy as np
    from scipy.linalg import expm
    from scipy.optimize import brentq
    from scipy.signal import lfilter

    from tank_control.core import scipy_lazy
    a = np.array([[0.0, 1.0], [-2.0, -0.3]])
    assert np.array_equal(scipy_lazy.expm(a), expm(a))
    assert scipy_lazy.brentq(np.cos, 1.0, 2.0) == brentq(np.cos, 1.0, 2.0)
    u = np.arange(5.0)
    assert np.array_equal(scipy_lazy.lfilter([0.5], [1.0, -0.5], u), lfilter([0.5], [1.0, -0.5], u))
