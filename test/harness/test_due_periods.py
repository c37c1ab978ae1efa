"""When an answer is due (the late-sample rule, README "Late samples"): on the period the
node actually samples, also when the scenario leaves its ``sample_time`` to the default."""
from pathlib import Path

from tank_control.harness.runner import due_periods
from tank_control.harness.scenario_file import load_scenario

CONFIG = Path(__file__).resolve().parents[2] / 'config'
MS = 1_000_000


def test_wall_reference_without_sample_time_is_due_on_its_default_period():
    """config/ipdt_pid.yaml states no reference sample_time: in wall the reference publishes
    every 1 s (its default), so r and d are due every 1 s, not every 10 ms plant tick (which
    counted every tick without a setpoint message as late: 1000 of 1001 in a 10 s run)."""
    scenario = load_scenario(CONFIG / 'ipdt_pid.yaml',
                             ['plant.sample_time=0.01', 'controller.sample_time=0.01'])
    assert due_periods(scenario, 'wall', 10 * MS) == {'u': 10 * MS, 'r': 1000 * MS,
                                                      'd': 1000 * MS}
    # sim and lockstep: the reference answers every /clock tick
    assert due_periods(scenario, 'lockstep', 10 * MS) == {'u': 10 * MS, 'r': 10 * MS,
                                                          'd': 10 * MS}


def test_controller_without_sample_time_is_due_on_its_kinds_default(tmp_path):
    text = (CONFIG / 'ipdt_pid.yaml').read_text().replace(
        'controller: pid\n    sample_time: 0.1\n', 'controller: pid\n')
    assert 'sample_time: 0.1\n    output_names' not in text
    path = tmp_path / 'no_controller_sample_time.yaml'
    path.write_text(text)
    due = due_periods(load_scenario(path), 'wall', 100 * MS)
    assert due['u'] == 1000 * MS          # the PID's declared default sample_time, 1 s


def test_a_period_that_is_no_whole_number_of_ticks_is_taken_as_the_tick():
    scenario = load_scenario(CONFIG / 'ipdt_pid.yaml', ['reference.sample_time=0.15'])
    assert due_periods(scenario, 'wall', 100 * MS)['r'] == 100 * MS
