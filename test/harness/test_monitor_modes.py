"""A run's manual and fail-safe times (metrics.json ``loop_performance.<output>.manual_pct``,
``fail_safe_pct``): logged by the controller as it samples (core/monitoring/modes.py), the same
numbers in-process and over ROS in lockstep, and equal to what the trace shows."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tank_control.core.monitoring.modes import ModeLog, flags_at
from tank_control.core.trace import Trace
from tank_control.harness.runner import run

TS = 0.5        # plant and controller sample time [s]
Y_MAX = 2.0     # the controller's range.y maximum: a measurement above it is refused


def _scenario(tmp_path: Path, mode: str, fail_safe: str) -> Path:
    """An FOPDT loop whose measurement rises above the controller's ``range.y`` in the run:
    ``mode`` manual with a constant output 3 (y tends to 3), or auto (PI with overshoot) with
    the setpoint 1.9 from t = 10 s; on a refused measurement the output is held
    (``fail_safe`` hold) or 0 (output)."""
    path = tmp_path / f'{mode}.yaml'
    path.write_text(f"""
plant:
  ros__parameters:
    plant: fopdt
    gain: 1.0
    time_constant: 20.0
    dead_time: 2.0
    sample_time: {TS}
    real_time_factor: 0.0
controller:
  ros__parameters:
    controller: pid
    sample_time: {TS}
    output_names: ['y']
    input_names: [u]
    kp: 8.0
    ti: 4.0
    u_min: -50.0
    u_max: 50.0
    mode: {mode}
    manual_output: 3.0
    fail_safe: {fail_safe}
    fail_safe_output: 0.0
    range.y: [-10.0, {Y_MAX}]
reference:
  ros__parameters:
    setpoint:
      channels: ['y']
      'y': {{times: [0.0, 10.0], values: [0.0, 1.9]}}
harness:
  ros__parameters:
    duration: 60.0
    clock_mode: lockstep
""")
    return path


def _expected(out: Path) -> tuple[float, float]:
    """The fail-safe time from the trace: controller samples whose measurement is refused."""
    trace = Trace.read_csv(out / 'trace.csv')
    return 100.0 * float(np.mean(trace['y.y'] > Y_MAX)), float(np.sum(trace['y.y'] > Y_MAX))


def test_mode_log_keeps_changes_and_gives_flags_per_sample() -> None:
    log = ModeLog()
    for k in range(10):
        log.add(k * 0.5, k >= 6, 2 <= k < 4)
    assert log.changes == [[0.0, False, False], [1.0, False, True], [2.0, False, False],
                           [3.0, True, False]]
    manual, fail_safe = flags_at(log.changes, np.arange(10) * 0.5)
    assert manual.tolist() == [k >= 6 for k in range(10)]
    assert fail_safe.tolist() == [2 <= k < 4 for k in range(10)]
    assert flags_at([], np.arange(3.0)) is None
    assert flags_at([['x', 1]], np.arange(3.0)) is None        # unreadable: not known


def test_in_process_run_has_its_fail_safe_time(tmp_path: Path) -> None:
    # auto: y overshoots 2, is refused, the output goes to 0 (fail-safe), y falls back below
    # 2, control resumes: several episodes
    result = run(_scenario(tmp_path, 'auto', 'output'), tmp_path / 'ip', in_process=True, plots=False)
    body = result.metrics['loop_performance']['y']
    pct, refused = _expected(tmp_path / 'ip')
    assert refused >= 5 and pct < 90.0
    assert body['manual_pct'] == 0.0
    assert body['fail_safe_pct'] == pytest.approx(pct, abs=1e-9)
    assert body['samples'] == len(result.trace)
    modes = result.metrics['run']['controller_modes']
    assert modes[0] == [0.0, False, False] and len(modes) >= 5     # episodes


def test_manual_and_fail_safe_times_over_ros_equal_in_process(tmp_path: Path, ros_env) -> None:
    # manual output 3: y crosses 2 at about 24 s of 60 s, then the output is held: fail-safe
    path = _scenario(tmp_path, 'manual', 'hold')
    ros = run(path, tmp_path / 'ros', plots=False)
    ref = run(path, tmp_path / 'ref', in_process=True, plots=False)
    assert ros.metrics['complete'], ros.metrics['reason']
    pct, refused = _expected(tmp_path / 'ref')
    assert 40.0 < pct < 80.0
    body = ref.metrics['loop_performance']['y']
    assert body['manual_pct'] == 100.0 and body['fail_safe_pct'] == pytest.approx(pct, abs=1e-9)
    assert body['verdict'] == 'in manual 100 % of the time'
    ros_body = json.loads((tmp_path / 'ros' / 'metrics.json').read_text())['loop_performance']['y']
    assert ros_body == json.loads((tmp_path / 'ref' / 'metrics.json').read_text())[
        'loop_performance']['y']
    assert ros.metrics['run']['controller_modes'] == ref.metrics['run']['controller_modes']
