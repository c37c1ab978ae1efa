"""In-process runs of shipped scenarios, each (name, overrides) once per test module."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from support import CONFIG, SCENARIOS

from tank_control.harness.runner import RunResult, run


def cached_runs(root: Path) -> Callable[..., RunResult]:
    """``get(name, *overrides)``: the run of config/scenarios/NAME.yaml (else config/NAME.yaml,
    e.g. the nodes' ipdt_pid) with ``--set`` overrides, made once, its files under ``root``;
    nothing drawn (``--no-plots``: the claims are in the trace and metrics)."""
    cache: dict[tuple, RunResult] = {}

    def get(name: str, *overrides: str) -> RunResult:
        key = (name, overrides)
        if key not in cache:
            path = SCENARIOS / f'{name}.yaml'
            path = path if path.exists() else CONFIG / f'{name}.yaml'
            cache[key] = run(path, root / f'{name}_{len(cache)}', overrides=overrides,
                             in_process=True, plots=False)
        return cache[key]
    return get
