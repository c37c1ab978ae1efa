"""The loop analysis a ROS run computes while it goes on (harness/analysis_ahead.py) is the one
computed after it, and is used only for the parameters it was computed for."""
from __future__ import annotations

from support import CONFIG

from tank_control.core.scenario_loops import loop_cases
from tank_control.harness.analysis_ahead import PART, AnalysisAhead
from tank_control.harness.scenario_file import load_scenario


def test_the_analysis_ahead_is_the_one_after_and_only_for_its_parameters(tmp_path):
    scenario = load_scenario(CONFIG / 'ipdt_pid.yaml')
    params = dict(scenario.sections['controller'])
    after = [case.report() for case in loop_cases(scenario.sections, params)]

    ahead = AnalysisAhead(scenario, tmp_path, 'title')
    ahead.start(params)
    cases = ahead.take(params)
    assert cases is not None and [case.report() for case in cases] == after
    assert (tmp_path / PART).stat().st_size > 0
    assert ahead.place(tmp_path / 'analysis.png') == tmp_path / 'analysis.png'
    assert not (tmp_path / PART).exists() and (tmp_path / 'analysis.png').exists()

    changed = AnalysisAhead(scenario, tmp_path, 'title')       # e.g. an auto-tuner's new gains
    changed.start(params)
    assert changed.take({**params, 'tuning.dead_time': 6.0}) is None
    assert not (tmp_path / PART).exists() and changed.place(tmp_path / 'x.png') is None

    nothing = AnalysisAhead(scenario, tmp_path, 'title')       # no controller: nothing to do
    assert nothing.take({}) is None and not (tmp_path / PART).exists()
