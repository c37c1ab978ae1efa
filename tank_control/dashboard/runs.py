"""The dashboard's runs page: the run folders under ``runs_dir`` and their files, read-only.

A run folder is one ``tank-control run --out`` folder (docs/harness.md): it holds
``metrics.json`` (scenario, title, complete flag, measured sections) and, when they were
written, ``plot.png`` and ``analysis.png``. The key metrics are those of a sweep's table
(``core/analysis/metrics_row.flat_metrics``: IAE, worst step, input use, loop robustness) and
each loop's performance verdict (``loop_performance``, docs/monitoring.md). Files are served
only from inside ``runs_dir``: :func:`run_file` refuses any path that resolves outside it.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from tank_control.dashboard.values import jsonable
from tank_control.core.analysis.metrics_row import flat_metrics

#: How deep run folders are looked for below ``runs_dir`` (a sweep nests its runs).
MAX_DEPTH = 3
#: The pictures a run may have, linked from the page.
PICTURES = ('plot.png', 'analysis.png')


def _run_folders(root: Path) -> list[Path]:
    found = []
    for folder, subfolders, files in os.walk(root, followlinks=False):
        depth = len(Path(folder).relative_to(root).parts)
        if 'metrics.json' in files and depth > 0:
            found.append(Path(folder))
        if depth >= MAX_DEPTH:
            subfolders.clear()
        subfolders.sort()
    return sorted(found)


def _run(root: Path, folder: Path) -> dict[str, Any]:
    name = folder.relative_to(root).as_posix()
    row: dict[str, Any] = {'name': name, 'scenario': '', 'title': '', 'complete': None,
                           'reason': '', 'error': '', 'metrics': {}, 'verdicts': {},
                           'files': [p for p in PICTURES if (folder / p).is_file()]}
    try:
        data = json.loads((folder / 'metrics.json').read_text())
        if not isinstance(data, dict):
            raise ValueError('not a JSON object')
    except (OSError, ValueError) as exc:
        row['error'] = f'{name}/metrics.json: not readable ({exc})'
        return row
    row.update(scenario=str(data.get('scenario') or ''), title=str(data.get('title') or ''),
               complete=data.get('complete'), reason=str(data.get('reason') or ''),
               mode=str(data.get('mode') or ''))
    performance = data.get('loop_performance')
    if isinstance(performance, dict):       # each loop's verdict (docs/monitoring.md)
        row['verdicts'] = {str(k): v['verdict'] for k, v in performance.items()
                           if isinstance(v, dict) and isinstance(v.get('verdict'), str)}
    try:
        row['metrics'] = {k: jsonable(v) for k, v in flat_metrics(data).items()}
    except (AttributeError, TypeError, ValueError) as exc:
        row['error'] = f'{name}/metrics.json: metrics not readable ({exc})'
    return row


def list_runs(runs_dir: str) -> dict[str, Any]:
    """The page's table: ``runs_dir``, ``hint`` (one line when there is nothing to list) and
    per run folder ``name`` (path below ``runs_dir``), ``scenario``, ``title``, ``complete``,
    ``reason``, ``mode``, ``metrics`` (flat) and ``files`` (the pictures present)."""
    if not runs_dir:
        return {'runs_dir': '', 'runs': [],
                'hint': 'no runs_dir: start dashboard_node with -p runs_dir:=<folder> (the '
                        'folder holding tank-control run --out folders)'}
    root = Path(runs_dir).expanduser()
    if not root.is_dir():
        return {'runs_dir': str(root), 'runs': [],
                'hint': f'runs_dir: {root} is not a folder'}
    root = root.resolve()
    runs = [_run(root, folder) for folder in _run_folders(root)]
    return {'runs_dir': str(root), 'runs': runs,
            'hint': '' if runs else f'runs_dir: no run folder (with metrics.json) in {root}'}


def run_file(runs_dir: str, relative: str) -> Path | None:
    """The file ``relative`` below ``runs_dir`` if it is a regular file inside it after
    resolving every ``..`` and symbolic link; None otherwise (also without ``runs_dir``)."""
    if not runs_dir or not relative or '\x00' in relative:
        return None
    root = Path(runs_dir).expanduser().resolve()
    try:
        path = (root / relative).resolve()
    except (OSError, RuntimeError, ValueError):
        return None
    if not path.is_relative_to(root) or path == root or not path.is_file():
        return None
    return path
