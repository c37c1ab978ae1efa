"""A run too long for the machine is refused before anything starts, with the numbers."""
from __future__ import annotations

import pytest

from support import CONFIG
from tank_control.harness import cli, runner
from tank_control.harness.scenario_file import ScenarioError, load_scenario

HUGE = ['plant.sample_time=1e-4', 'controller.sample_time=1e-3', 'harness.duration=1e7']


@pytest.mark.parametrize('in_process', [True, False])
def test_a_run_that_cannot_fit_in_memory_is_refused_before_it_starts(tmp_path, in_process):
    scenario = load_scenario(CONFIG / 'ipdt_pid.yaml', HUGE)
    with pytest.raises(ScenarioError, match=r'1e\+11 ticks, which would need about .* GiB of '
                       r'memory; .* GiB are available: shorten the run or lengthen the tick'):
        runner.run_scenario(scenario, tmp_path / 'out', in_process=in_process)
    assert not (tmp_path / 'out').exists()           # nothing written, no node started
    assert runner.size_reason(load_scenario(CONFIG / 'ipdt_pid.yaml'), in_process) is None


def test_the_command_says_so_in_one_line(tmp_path, capsys):
    code = cli.main(['run', str(CONFIG / 'ipdt_pid.yaml'), '--out', str(tmp_path), '--in-process',
                     *[x for item in HUGE for x in ('--set', item)]])
    err = capsys.readouterr().err
    assert code == 2 and 'would need about' in err and 'Traceback' not in err
    assert len(err.strip().splitlines()) == 1
