"""Every benchmark script in bench/ still imports against the package (they are run by hand to
refresh bench/RESULTS.md, so a renamed function would otherwise break them unnoticed)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / 'bench'


@pytest.mark.parametrize('script', sorted(BENCH.glob('*.py')), ids=lambda p: p.name)
def test_bench_script_imports(script: Path) -> None:
    spec = importlib.util.spec_from_file_location(f'bench_{script.stem}', script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)          # top level only: the scripts run under __main__
    assert callable(getattr(module, 'main', None)), f'{script.name} has no main()'
