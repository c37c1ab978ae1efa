"""Kinds answer for themselves (issue 32 §2, issue 33 §2): every controller kind with a linear
description (``ControllerKind.linear``) on a plant kind with one (``PlantKind.linear``) is
analysed — ``tank-control analyze``, ``analysis.png``, the dashboard's panel — with no list of
kind names. The margins printed are checked against what the loop does when simulated: a
loop with a little less extra delay (or gain change) than the margin settles, a little more
diverges."""
from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

from tank_control.core import scenario as core_scenario
from tank_control.core.analysis.linear import pid_controller
from tank_control.core.scenario_loops import describe_loop, loop_cases
from tank_control.core.analysis.robustness import loop_report, smith_report
from tank_control.core.control.kinds import registry
from tank_control.core.control.kinds.base import ControllerKind, channels
from tank_control.core.control.pid import PidConfig, PidController
from tank_control.core.params import param
from tank_control.core.plants.kinds.registry import make_plant
from tank_control.core.tuning.model import ProcessModel
from tank_control.dashboard.robustness import loop_analysis
from tank_control.harness.scenario_file import load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / 'config' / 'scenarios'


def sections(name: str, *overrides: str):
    return load_scenario(SCENARIOS / name, overrides).sections


def report_of(name: str, *overrides: str):
    cases = loop_cases(sections(name, *overrides))
    assert cases and cases[0].label.startswith('plant'), name
    return cases[0].report()


def tail_error(name: str, plant_changes: dict, duration: float) -> float:
    """The largest |r − y| over the last tenth of a simulation of the scenario's controller
    (output limits removed: the linear loop) on its plant with ``plant_changes``, setpoint 1."""
    s = sections(name)
    values = core_scenario.node_values(s, 'controller')
    fixed = ({'u_min': -1e9, 'u_max': 1e9} if 'u_min' in values else {})
    if 'autotune.start_time' in values:
        fixed['autotune.start_time'] = 0.0            # no relay test: the loop as analysed
    ctrl = core_scenario.controller_setup({**values, **fixed}).build_controller()
    plant_values = core_scenario.node_values(s, 'plant')
    kind = plant_values['plant']
    model = {k: v for k, v in plant_values.items()
             if k in {sp.name for sp in core_scenario.plants.get_kind(kind).specs()}}
    plant = make_plant(kind, {**model, **plant_changes})
    h = ctrl.sample_time
    n = int(round(duration / h))
    errors = np.empty(n)
    d = np.zeros(len(plant.disturbance_names))
    for k in range(n):
        y = plant.outputs()
        errors[k] = 1.0 - y[0]
        u = ctrl.step(k * h, y, np.array([1.0]), np.array([]))
        plant.step(u, d, h)
    return float(np.max(np.abs(errors[-n // 10:])))


@pytest.mark.parametrize('name', ['tf_002_pd.yaml', 'fopdt_smith_autotune.yaml',
                                  'fopdt_fsa.yaml', 'foupdt_fsa.yaml'])
def test_analyze_prints_margins_and_ms_of_lead_lag_smith_and_fsa(name):
    out = subprocess.run([sys.executable, '-m', 'tank_control.harness.cli', 'analyze',
                          str(SCENARIOS / name)], capture_output=True, text=True, timeout=300,
                         cwd=ROOT)
    assert out.returncode == 0, out.stderr
    rows = [line for line in out.stdout.splitlines() if line.startswith('| plant')]
    assert len(rows) == 1, out.stdout
    cells = [c.strip() for c in rows[0].strip('|').split('|')]
    report = report_of(name)
    assert cells[1] == 'yes' and report.stable
    assert float(cells[3]) == pytest.approx(report.phase_margin, abs=0.05)
    assert float(cells[4]) == pytest.approx(report.ms, abs=0.006)     # 3 digits printed
    assert 0 < report.phase_margin < 180 and 1 < report.ms < 5 and report.delay_margin > 0


def test_the_lead_lag_margins_are_those_of_its_own_robustness_guard():
    """The kind's description and the analysis its ``robustness.*`` results use agree on the
    tuning model (here equal to the plant, 002's 4/((s + 1)(s + 2)))."""
    from tank_control.core.control.kinds import lead_lag
    s = sections('tf_002_pd.yaml')
    setup = core_scenario.controller_setup(core_scenario.node_values(s, 'controller'))
    guard = lead_lag.loop_report(lead_lag.process_model(setup.settings.values),
                                 setup.settings.config)
    ours = report_of('tf_002_pd.yaml')
    for key in ('gain_margin', 'phase_margin', 'ms', 'mt', 'delay_margin'):
        assert getattr(ours, key) == pytest.approx(getattr(guard, key), rel=1e-6), key


def test_the_smith_predictor_on_its_own_model_is_smith_report():
    name, over = 'fopdt_smith_autotune.yaml', ('plant.dead_time=3.5', 'plant.time_constant=12.0')
    setup = core_scenario.controller_setup(core_scenario.node_values(sections(name), 'controller'))
    cases = loop_cases(sections(name, *over))
    assert len(cases) == 1                                  # plant = the internal model
    expected = smith_report(ProcessModel('fopdt', 0.05, 3.5, 12.0), setup.settings.primary)
    got = cases[0].report()
    assert got.stable is expected.stable is True
    for key in ('gain_margin', 'phase_margin', 'ms', 'mt', 'delay_margin'):
        assert getattr(got, key) == pytest.approx(getattr(expected, key), rel=1e-6), key


@pytest.mark.parametrize('name, duration', [('fopdt_fsa.yaml', 2500.0),
                                            ('foupdt_fsa.yaml', 1500.0),
                                            ('fopdt_smith_autotune.yaml', 3000.0)])
def test_the_delay_margin_printed_is_where_the_simulated_loop_turns_unstable(name, duration):
    """Plant dead time + 0.85·(delay margin): the loop settles; + 1.15·: it diverges. For the
    Smith predictor the plant differs from its internal model (stability from
    C·(Gm0 − Gm + G)); the FSA's law has its own unstable poles on the unstable plant."""
    report = report_of(name)
    dead = core_scenario.node_values(sections(name), 'plant')['dead_time']
    settles = tail_error(name, {'dead_time': dead + 0.85 * report.delay_margin}, duration)
    diverges = tail_error(name, {'dead_time': dead + 1.15 * report.delay_margin}, duration)
    assert settles < 1e-3, (report.delay_margin, settles)
    assert diverges > 1.0, (report.delay_margin, diverges)


@pytest.mark.parametrize('name, duration', [('fopdt_fsa.yaml', 2500.0),
                                            ('foupdt_fsa.yaml', 3000.0)])
def test_the_gain_margin_printed_is_where_the_simulated_loop_turns_unstable(name, duration):
    """A plant gain of 0.95·/1.05·(gain margin) around the stability limit (below 1 for the
    unstable plant: a lower gain loses it)."""
    gm = report_of(name).gain_margin
    low, high = (tail_error(name, {'gain': f * gm}, duration) for f in (0.95, 1.05))
    stable, unstable = (low, high) if gm > 1 else (high, low)
    assert stable < 1e-3 and unstable > 1.0, (gm, low, high)


# ------------------------------------------------------------ a kind nobody lists
@dataclass(frozen=True)
class PConfig:
    kp: float = param(2.0, 'gain', unit='-', min=0.0, max=100.0)
    sample_time: float = param(0.1, 'sample time', unit='s', min=1e-3, max=10.0)


def _p_build(settings):
    return PidController(PidConfig(kp=settings.config.kp, sample_time=settings.config.sample_time))


P_ONLY = ControllerKind(
    name='p_only', description='a P controller that describes itself', config=PConfig,
    groups=(channels(('y',), ('u',)),), build=_p_build,
    linear=lambda s: pid_controller(PidConfig(kp=s.config.kp, sample_time=s.config.sample_time)))


def test_a_new_kind_with_a_linear_description_is_analysed_with_no_edit_elsewhere(monkeypatch):
    monkeypatch.setitem(registry.KINDS, 'p_only', P_ONLY)
    plant = {'plant': 'fopdt', 'gain': 0.5, 'time_constant': 10.0, 'dead_time': 3.0}
    controller = {'controller': 'p_only', 'kp': 2.0}
    cases, reason = describe_loop(plant, controller)
    assert reason == '' and len(cases) == 1
    expected = loop_report(ProcessModel('fopdt', 0.5, 3.0, 10.0),
                           PidConfig(kp=2.0, sample_time=0.1))
    assert cases[0].report() == expected
    panel = loop_analysis(plant, controller)
    assert panel['available'] and panel['cases'][0]['margins']['ms'] == pytest.approx(
        expected.ms, rel=1e-12)
    # without a description: one line naming the kind and what it lacks
    monkeypatch.setitem(registry.KINDS, 'p_only', replace(P_ONLY, linear=None))
    panel = loop_analysis(plant, controller)
    assert not panel['available']
    assert panel['reason'].startswith('controller p_only: the kind gives no linear description')


def test_the_dashboard_analyses_fsa_on_an_unstable_plant():
    s = sections('foupdt_fsa.yaml')
    panel = loop_analysis(core_scenario.node_values(s, 'plant'),
                          core_scenario.node_values(s, 'controller'))
    assert panel['available'], panel['reason']
    margins = panel['cases'][0]['margins']
    assert margins['stable'] is True and math.isfinite(margins['ms'])
    assert panel['controller'].startswith('FSA w0 0.2 rad/s')


def test_no_list_of_kind_names_decides_the_analysis():
    import tank_control.core.scenario_loops as loops
    import tank_control.core.tuning.model as model
    import tank_control.dashboard.robustness as panel
    assert not hasattr(loops, 'PID_KINDS') and not hasattr(model, 'from_plant')
    source = Path(panel.__file__).read_text() + Path(loops.__file__).read_text()
    for name in ('transfer_function', "'pid'", 'relay_autotune'):
        assert name not in source
