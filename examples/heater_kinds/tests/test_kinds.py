"""The example kinds checked with tank_control's conformance kit (tank_control.testing):
copy this file into your package's tests."""
from pathlib import Path


from tank_control.testing import check_controller_kind, check_plant_kind, run_scenario

SCENARIO = Path(__file__).resolve().parents[1] / 'scenarios' / 'heater_on_off.yaml'


def test_on_off_meets_the_controller_contract():
    # at the setpoint (inside the hysteresis band) the output holds: reset, manual/auto and
    # live changes are bumpless; errors of ±100 drive it to its limits
    report = check_controller_kind('on_off', {'u_min': 0.0, 'u_max': 60.0, 'hysteresis': 1.0},
                                   y0=20.0, r0=20.0)
    assert 'manual/auto' in report.checked and 'output limits and anti-windup' in report.checked


def test_heater_meets_the_plant_contract():
    report = check_plant_kind('heater', u=30.0)
    assert 'linear description' in report.not_applicable      # the deadband is not linear


def test_the_loop_cycles_around_the_setpoint_within_its_limits(tmp_path):
    metrics = run_scenario(SCENARIO, out_dir=tmp_path / 'run')
    assert metrics['complete']
    step = metrics['outputs']['y']['steps'][0]             # 20 -> 35 °C at t = 20 s
    # the dead time makes an on/off loop cycle: it stays within 2 °C of the setpoint
    assert abs(step['ss_error']) < 2.0 and step['peak'] < 35.0 + 2.0
    assert metrics['inputs']['u']['constraint_violations'] == 0
