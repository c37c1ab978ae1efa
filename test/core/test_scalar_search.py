"""core/scalar_search.py: the root finder and the maximiser the frequency analysis uses instead of
scipy.optimize (whose import cost every controller node 0.25 s of CPU at start-up) give
scipy's results to within the same tolerances, and a controller's loop report no longer
imports scipy.optimize."""
from __future__ import annotations

import math
import random
import subprocess
import sys

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from tank_control.core.scalar_search import bounded_max, bracketed_root


def _functions(rng: random.Random):
    """Smooth, steep, flat-ended and wavy functions with one root in the bracket."""
    for k in range(400):
        r, s = rng.uniform(-50.0, 50.0), rng.uniform(0.1, 10.0)
        f = [lambda x, r=r, s=s: math.tanh(s * (x - r)),
             lambda x, r=r, s=s: (x - r) ** 3 + s * (x - r),
             lambda x, r=r, s=s: math.expm1(s * (x - r) / 50.0),
             lambda x, r=r: math.atan(x - r) * (1.0 + 0.5 * math.sin(x))][k % 4]
        yield f, r - rng.uniform(0.01, 60.0), r + rng.uniform(0.01, 60.0)


def test_roots_equal_brentq_within_the_tolerance():
    worst = 0.0
    for f, a, b in _functions(random.Random(7)):
        ours = bracketed_root(f, a, b, xtol=1e-14, rtol=1e-13)
        theirs = brentq(f, a, b, xtol=1e-14, rtol=1e-13)
        assert a <= ours <= b
        worst = max(worst, abs(ours - theirs) / (1e-14 + 1e-13 * abs(theirs)))
    # both within their tolerance of the root: at most two tolerances apart
    assert worst <= 2.0


def test_a_root_at_an_end_and_a_bad_bracket():
    assert bracketed_root(lambda x: x - 1.0, 1.0, 3.0) == 1.0
    assert bracketed_root(lambda x: x - 3.0, 1.0, 3.0) == 3.0
    with pytest.raises(ValueError, match='same sign'):
        bracketed_root(lambda x: x * x + 1.0, -1.0, 1.0)
    with pytest.raises(ValueError, match='not finite'):
        bracketed_root(lambda x: math.nan, -1.0, 1.0)


def test_a_flat_function_is_solved_no_slower_than_bisection():
    """x^9 (scipy's brentq gives up on it at these tolerances): regula falsi alone creeps from
    one end; a bisection whenever three steps did not halve the bracket bounds the work to
    four evaluations per halving."""
    calls = []

    def f(x):
        calls.append(x)
        return (x - 0.3) ** 9
    x = bracketed_root(f, -10.0, 10.0, xtol=1e-14, rtol=1e-13)
    # the 9th power is flat at its root: every x within (2.2e-16)^(1/9) of it evaluates to 0
    # or has the right sign, so the result is within that band
    assert abs(x - 0.3) < 2e-2
    assert len(calls) <= 2 + 4 * math.ceil(math.log2(20.0 / 1e-14))


def test_the_maximum_equals_scipys_bounded_search():
    rng = random.Random(3)
    for _ in range(300):
        m, w = rng.uniform(-3.0, 3.0), rng.uniform(0.5, 3.0)

        def f(x, m=m, w=w):
            return 1.0 / (1.0 + ((x - m) / w) ** 2) + 0.01 * np.sin(x)
        lo, hi = m - rng.uniform(0.1, 1.0), m + rng.uniform(0.1, 1.0)
        x, value = bounded_max(f, lo, hi, xatol=1e-12)
        theirs = minimize_scalar(lambda x: -f(x), bounds=(lo, hi), method='bounded',
                                 options={'xatol': 1e-12})
        assert lo <= x <= hi and value == f(np.asarray([x]))[0]
        assert value == pytest.approx(-theirs.fun, rel=1e-14)


def test_a_controller_report_does_not_import_scipy_optimize():
    """What controller_node computes for its first /diagnostics (the loop's margins on the
    tuning model) in a fresh interpreter: scipy.optimize stays unimported."""
    code = '''
import sys
from tank_control.core import params_file
from tank_control.core.scenario import controller_setup
import tank_control.nodes.controller_node
values = params_file.node_values(params_file.read("config/ipdt_pid.yaml"), "controller")
setup = controller_setup(values)
controller = setup.build_controller()
results = setup.kind.results(controller)
assert results["robustness.ms"] > 1.0, results
print(sorted(m for m in sys.modules if m.startswith("scipy.optimize")))
'''
    from support import REPO
    done = subprocess.run([sys.executable, '-c', code], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == '[]'
