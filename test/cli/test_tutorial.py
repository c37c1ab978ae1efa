"""docs/tutorial.md works as written: every command line in it is accepted by its parser (the
project's ``tank-control`` and ``ros2``, ``ros2 run`` finds the executable, ``make`` has the
target), every file it names exists, the README links to it, and its ``tank-control`` commands
that need no live graph run and print the numbers the tutorial quotes."""
from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from tank_control.harness import cli
from tank_control.ros2cli import main as ros2_main
from tank_control.ros2cli import run as ros2_run

ROOT = Path(__file__).resolve().parents[2]
TUTORIAL = ROOT / 'docs' / 'tutorial.md'


def commands() -> list[str]:
    """The indented code lines (4 spaces) of the tutorial, continuation lines joined."""
    lines = [line[4:] for line in TUTORIAL.read_text().splitlines() if line.startswith('    ')]
    return [line for line in lines if line.strip()]


def test_the_readme_links_the_tutorial():
    assert 'docs/tutorial.md' in (ROOT / 'README.md').read_text()


def test_every_command_line_parses_and_every_file_it_names_exists():
    seen = set()
    makefile = (ROOT / 'Makefile').read_text()
    for line in commands():
        argv = shlex.split(line)
        seen.add(argv[0])
        if argv[0] == 'make':
            assert re.search(rf'^{argv[1]}:', makefile, re.M), line
        elif argv[0] == 'source':
            assert argv[1] == '.venv/bin/activate', line
        elif argv[0] == 'export':
            assert all(re.fullmatch(r'[A-Z_]+=\S+', a) for a in argv[1:]), line
        elif argv[:2] == ['ros2', 'run']:
            assert ros2_run.is_run_command(argv[1:]), line
            assert argv[2] == 'tank_control' and ros2_run.resolve(argv[2], argv[3]), line
        elif argv[0] in ('ros2', 'tank-control'):
            root = cli._parser() if argv[0] == 'tank-control' else ros2_main.build_parser()
            with contextlib.redirect_stderr(io.StringIO()) as err:
                try:
                    root.parse_args(argv[1:])
                except SystemExit:
                    pytest.fail(f'{line!r} is refused: {err.getvalue()}')
        else:
            pytest.fail(f'unexpected command in the tutorial: {line!r}')
    assert {'make', 'tank-control', 'ros2'} <= seen
    named = set(re.findall(r'(?<![\w/])((?:config|docs|test)/[\w/.-]+\.(?:yaml|md|py))',
                           TUTORIAL.read_text()))
    assert 'config/fopdt_autotune.yaml' in named
    missing = [n for n in named if not (ROOT / n).is_file()]
    assert not missing, missing


def test_ros2_commands_name_the_nodes_of_the_file_they_start():
    """The nodes the tutorial talks to are the nodes its file starts."""
    from tank_control.core import params_file
    started = set()
    for line in commands():
        argv = shlex.split(line)
        if argv[:2] == ['ros2', 'run'] and '--params-file' in argv:
            started.add(argv[argv.index('--params-file') + 1])
    (path,) = started
    sections = params_file.read(ROOT / path)
    targets = {a for line in commands() for a in shlex.split(line)
               if re.fullmatch(r'/(plant|controller|reference)', a)}
    assert targets == {'/controller', '/reference'}
    assert {t[1:] for t in targets} <= set(sections)
    assert sections['controller']['autotune.start_time'] == 0.0     # nothing starts by itself


def run_cli(argv: list[str], capsys) -> str:
    assert cli.main(argv) == 0, argv
    return capsys.readouterr().out


@pytest.mark.slow
def test_its_offline_tank_control_commands_run_and_print_the_quoted_numbers(tmp_path, capsys,
                                                                           monkeypatch):
    monkeypatch.chdir(ROOT)
    text = TUTORIAL.read_text()
    ran = []
    for line in commands():
        argv = shlex.split(line)
        if argv[0] != 'tank-control':
            continue
        if argv[1] == 'run' and '--in-process' not in argv:
            continue                           # over ROS: the in-process twin is run instead
        if '--out' in argv:
            i = argv.index('--out') + 1
            argv[i] = str(tmp_path / argv[i])
        ran.append(argv[1])
        out = run_cli(argv[1:] + (['--quiet'] if argv[1] == 'run' else []), capsys)
        if argv[1] == 'analyze':
            assert '| yes | 5.3 | 79.2 | 1.29 |' in out
            assert 'GM 5.3, PM 79.2°, Ms 1.29' in text
        elif argv[1] == 'run' and argv[2] == 'config/ipdt_pid.yaml' and '--set' not in argv:
            assert '| ipdt_pid | y | 11.37 |' in out and '| 0.0189 | 12.7 | 26.1 |' in out
            assert 'IAE 11.37, overshoot 0.02 %, settling 26.1 s' in text
            assert all((tmp_path / 'runs/ipdt' / f).is_file() for f in
                       ('plot.png', 'analysis.png', 'trace.csv', 'metrics.json'))
        elif argv[1] == 'list':
            assert 'config/fopdt_autotune.yaml' in out
    assert sorted(ran) == ['analyze', 'list', 'run', 'run']
