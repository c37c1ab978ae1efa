"""The package passes its static checks (``make lint``): ruff (ruff.toml: pyflakes, pycodestyle's
errors and warnings, bugbear, line length) and mypy (setup.cfg ``[mypy]``). A finding fails the
suite with the tool's own report; the tools are the pinned ones of this interpreter's environment."""
from __future__ import annotations

import ast
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


def _imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, at its top or inside a function."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f'{node.module}.{alias.name}' for alias in node.names)
    return found


def test_the_harness_does_not_import_the_demo() -> None:
    """The demo is a user of the harness (``make demo``), never a part of it."""
    users = sorted(str(path.relative_to(ROOT))
                   for path in (ROOT / 'tank_control' / 'harness').rglob('*.py')
                   if 'tank_control.demo' in _imported_modules(path))
    assert not users, f'harness modules importing tank_control.demo: {users}'


def test_node_classes_stay_thin_adapters() -> None:
    """Each node file stays a thin adapter (parameters -> kind -> clock object -> publish):
    at most 400 lines, and no branch on the clock mode — what differs between wall, sim and
    lockstep lives in the clock protocol objects (tank_control/nodes/protocol/)."""
    nodes = sorted((ROOT / 'tank_control' / 'nodes').glob('*_node.py'))
    assert nodes
    long = {p.name: n for p in nodes if (n := len(p.read_text().splitlines())) > 400}
    assert not long, f'node files over 400 lines: {long}'
    branches = []
    for path in nodes:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare):
                text = ast.unparse(node)
                if 'mode' in ast.unparse(node.left) and any(
                        isinstance(c, ast.Constant) and c.value in ('wall', 'sim', 'lockstep')
                        for c in ast.walk(node)):
                    branches.append(f'{path.name}:{node.lineno}: {text}')
    assert not branches, 'clock-mode branches in node files:\n' + '\n'.join(branches)
