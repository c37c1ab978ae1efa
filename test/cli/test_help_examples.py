"""``--help`` of every command the project ships (``tank-control`` and its sub-commands, the
``ros2`` verbs) ends with examples, each of which its parser accepts and whose files exist;
``tank-control list`` shows every shipped scenario and study with its title."""
from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tank_control import cli_examples
from tank_control.harness import cli
from tank_control.ros2cli import main as ros2_main
from tank_control.ros2cli import run as ros2_run

ROOT = Path(__file__).resolve().parents[2]


def parsers() -> list[argparse.ArgumentParser]:
    top = [cli._parser(), ros2_main.build_parser()]
    found = [p for t in top for p in (t, *cli_examples.sub_parsers(t))]
    return found


def words(example: str) -> list[str]:
    return shlex.split(example.split(' > ')[0])


def test_every_parser_has_examples_that_it_accepts():
    progs = []
    for parser in parsers():
        progs.append(parser.prog)
        help_text = parser.format_help()
        assert '\nexamples:\n' in help_text, f'{parser.prog} --help has no examples'
        examples = cli_examples.EXAMPLES[parser.prog]
        for example in examples:
            assert example in help_text, (parser.prog, example)    # kept on one line
            argv = words(example)
            top = ' '.join(argv[:1])
            assert example.startswith(parser.prog), (parser.prog, example)
            if argv[:2] == ['ros2', 'run']:
                continue                        # parsed by hand: test_ros2_run_examples
            root = cli._parser() if top == 'tank-control' else ros2_main.build_parser()
            with contextlib.redirect_stderr(io.StringIO()) as err:
                try:
                    root.parse_args(argv[1:])
                except SystemExit:
                    pytest.fail(f'{example!r} is refused: {err.getvalue()}')
            for word in argv:                   # the shipped files it names exist
                if word.startswith('config/'):
                    assert (ROOT / word).exists(), (example, word)
    assert {'tank-control run', 'tank-control compare', 'tank-control analyze',
            'tank-control sweep', 'tank-control list', 'ros2 param set', 'ros2 topic echo',
            'ros2 service call', 'ros2 node list'} <= set(progs)


def test_ros2_run_examples(capsys):
    assert ros2_run.main_from_argv(['-h']) == 0
    out = capsys.readouterr().out
    assert '\nexamples:\n' in out
    for example in cli_examples.EXAMPLES['ros2 run']:
        argv = words(example)
        assert ros2_run.is_run_command(argv[1:])
        package, executable = argv[2:4]
        assert package == 'tank_control'
        assert ros2_run.resolve(package, executable)          # the executable is found
        for word in argv:
            if word.startswith('config/'):
                assert (ROOT / word).is_file(), (example, word)
        assert executable in out


def test_every_command_help_prints_examples():
    """Through the installed console scripts, as a user types them."""
    for argv in (['tank-control', 'list', '--help'], ['tank-control', 'run', '--help'],
                 ['ros2', 'topic', 'echo', '--help']):
        exe = Path(sys.executable).parent / argv[0]
        out = subprocess.run([str(exe), *argv[1:]], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        assert '\nexamples:\n  ' + ' '.join(argv[:-1]) in out.stdout, out.stdout


def test_list_shows_every_shipped_scenario_with_its_title(capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    assert cli.main(['list']) == 0
    lines = capsys.readouterr().out.splitlines()
    shipped = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / 'config').rglob('*.yaml'))
    listed = {}
    for line in lines:
        path, _, title = line.partition(' ')
        listed[path] = title.strip()
    assert sorted(listed) == shipped
    assert all(listed.values()), [p for p, t in listed.items() if not t]
    assert listed['config/ipdt_pid.yaml'].startswith('[Viteckova] IPDT')
    assert listed['config/scenarios/tank_mpcs_qp.yaml'].startswith('[Michalski2021] §6 MPCS, QP solver')
    assert listed['config/studies/000_robustness.yaml'].startswith('[Viteckova]: MDP')
    assert lines[0].startswith('config/') and '/' not in lines[0].split()[0][len('config/'):]


def test_list_of_a_folder_and_a_broken_file(tmp_path, capsys):
    (tmp_path / 'a.yaml').write_text('# first line of the comment\nplant: {ros__parameters: {}}\n')
    (tmp_path / 'b.yaml').write_text('plant: [\n')
    assert cli.main(['list', '--dir', str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert 'a.yaml  first line of the comment' in out
    assert re.search(r'b\.yaml  \(not valid YAML: ', out)
    assert cli.main(['list', '--dir', str(tmp_path / 'none')]) == 2
    assert 'not a directory' in capsys.readouterr().err
