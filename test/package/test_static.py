"""The package passes its static checks (``make lint``): ruff (ruff.toml: pyflakes, pycodestyle's
errors and warnings, bugbear, line length) and mypy (setup.cfg ``[mypy]``). A finding fails the
suite with the tool's own report; the tools are the pinned ones of this interpreter's environment."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _run(*command: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, '-m', *command], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


def test_ruff_finds_nothing() -> None:
    done = _run('ruff', 'check', '--no-cache', 'tank_control')
    if done.returncode != 0:
        pytest.fail(f'ruff check tank_control:\n{done.stdout}{done.stderr}', pytrace=False)


def test_mypy_finds_nothing() -> None:
    done = _run('mypy', 'tank_control')
    if done.returncode != 0:
        pytest.fail(f'mypy tank_control:\n{done.stdout}{done.stderr}', pytrace=False)
