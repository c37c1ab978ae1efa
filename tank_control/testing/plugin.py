"""pytest plugin of the kit (entry point ``pytest11``): fixtures for users' tests of their
kinds. Importing it loads no ROS package."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest


@pytest.fixture
def tank_control_run(tmp_path: Path) -> Callable[..., dict[str, Any]]:
    """``run(path, overrides=(), mode='in-process', duration=None) -> metrics``: a scenario
    run whose files go to ``tmp_path/run<N>``."""
    from tank_control.testing.contract import run_scenario
    count = [0]

    def run(path: Any, overrides: Sequence[str] = (), mode: str = 'in-process',
            duration: float | None = None) -> dict[str, Any]:
        count[0] += 1
        return run_scenario(path, overrides, mode=mode, out_dir=tmp_path / f'run{count[0]}',
                            duration=duration)
    return run
