"""``ros2 run PKG EXE [args...]``: find an executable of a package and run it.

Resolution, as ros2cli does it: the package is looked up in the ament resource
index (``<prefix>/share/ament_index/resource_index/packages/PKG``) of every
prefix in ``AMENT_PREFIX_PATH`` and then ``sys.prefix`` (where pip puts a
package's data_files); the executable is searched under ``<prefix>/lib/PKG``
(a colcon install). A pip install puts console scripts in ``bin/`` instead, so
the package's declared console scripts (distribution entry points) are the
fallback.

The command replaces itself with the executable (``exec``): signals sent to
``ros2 run`` (SIGINT, SIGTERM) reach the executable directly, exactly once,
and the exit code of ``ros2 run`` is the executable's.
"""
from __future__ import annotations

import argparse
import os
import shlex
import sys
import sysconfig
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:
    from importlib import metadata

from tank_control import cli_examples
from tank_control.ros2cli.common import CliError

_INDEX = Path('share', 'ament_index', 'resource_index', 'packages')


def add_parser(commands: argparse._SubParsersAction) -> None:
    parser = commands.add_parser(
        'run', help='Run a package specific executable',
        description='Run a package specific executable. Everything after EXECUTABLE '
                    '(e.g. --ros-args -p name:=value --params-file f.yaml) is passed to it.')
    _fill_parser(parser)


def _fill_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--prefix', metavar='PREFIX',
                        help="prefix command, e.g. 'gdb -ex run --args'")
    parser.add_argument('package_name', metavar='PACKAGE', help='name of the ROS package')
    parser.add_argument('executable_name', metavar='EXECUTABLE',
                        help='name of the executable')
    parser.add_argument('argv', metavar='...', nargs=argparse.REMAINDER,
                        help='arguments passed to the executable')
    parser.set_defaults(func=lambda args: run(args.package_name, args.executable_name,
                                              args.argv, args.prefix))


def is_run_command(argv: Sequence[str]) -> bool:
    return bool(argv) and argv[0] == 'run'


def main_from_argv(argv: Sequence[str]) -> int:
    """Parse ``[--prefix P] [-h] PACKAGE EXECUTABLE [args...]`` by hand.

    argparse would take the executable's own options (``-p``, ``--ros-args``) as
    ours; only options before PACKAGE belong to ``ros2 run``.
    """
    parser = argparse.ArgumentParser(prog='ros2 run', description=(
        'Run a package specific executable. Everything after EXECUTABLE is passed to it.'))
    _fill_parser(parser)
    cli_examples.attach(parser)
    argv = list(argv)
    prefix = None
    while argv and argv[0].startswith('-'):
        option = argv.pop(0)
        if option in ('-h', '--help'):
            parser.print_help()
            return 0
        if option == '--prefix' and argv:
            prefix = argv.pop(0)
        elif option.startswith('--prefix='):
            prefix = option.split('=', 1)[1]
        else:
            parser.error(f'unrecognized argument: {option}')
    if len(argv) < 2:
        parser.error('the following arguments are required: PACKAGE, EXECUTABLE')
    return run(argv[0], argv[1], argv[2:], prefix)


def ament_prefixes() -> list[Path]:
    """``AMENT_PREFIX_PATH`` entries, then ``sys.prefix`` (pip's data_files prefix)."""
    entries = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes = [Path(p) for p in entries]
    if Path(sys.prefix) not in prefixes:
        prefixes.append(Path(sys.prefix))
    return prefixes


def package_prefix(package: str) -> Path | None:
    """The first prefix whose ament index registers ``package`` (ament's precedence)."""
    for prefix in ament_prefixes():
        if (prefix / _INDEX / package).is_file():
            return prefix
    return None


def executables_in_prefix(prefix: Path, package: str, executable: str) -> list[Path]:
    """Executable files named ``executable`` under ``<prefix>/lib/<package>``."""
    found = []
    for dirpath, dirnames, filenames in os.walk(prefix / 'lib' / package):
        dirnames[:] = sorted(d for d in dirnames if d[0] not in '._')
        if executable in filenames:
            path = Path(dirpath, executable)
            if os.access(path, os.X_OK):
                found.append(path)
    return found


def _distribution(package: str) -> 'metadata.Distribution | None':
    from importlib import metadata
    for name in (package, package.replace('_', '-'), package.replace('-', '_')):
        try:
            return metadata.distribution(name)
        except metadata.PackageNotFoundError:
            continue
    return None


def console_script_command(package: str, executable: str) -> list[str] | Literal[False] | None:
    """argv running a console script of distribution ``package``.

    None: no such distribution; False: the distribution has no such script.
    The generated script in the scripts directory is preferred; without it the
    entry point is called through this interpreter.
    """
    dist = _distribution(package)
    if dist is None:
        return None
    for entry in dist.entry_points:
        if entry.group == 'console_scripts' and entry.name == executable:
            script = Path(sysconfig.get_path('scripts'), executable)
            if script.is_file() and os.access(script, os.X_OK):
                return [str(script)]
            code = ('import sys; from importlib.metadata import EntryPoint; '
                    f'sys.argv[0] = {executable!r}; '
                    f'sys.exit(EntryPoint({executable!r}, {entry.value!r}, '
                    "'console_scripts').load()())")
            return [sys.executable, '-c', code]
    return False


def resolve(package: str, executable: str) -> list[str]:
    """argv of the executable, or CliError with ros2cli's message."""
    prefix = package_prefix(package)
    if prefix is not None:
        paths = executables_in_prefix(prefix, package, executable)
        if len(paths) > 1:
            listing = ''.join(f'\n- {p}' for p in paths)
            raise CliError('Multiple executables found:' + listing)
        if paths:
            return [str(paths[0])]
    command = console_script_command(package, executable)
    if command:
        return command
    if prefix is None and command is None:
        raise CliError(f"Package '{package}' not found")
    raise CliError('No executable found')


def run(package: str, executable: str, argv: Sequence[str], prefix: str | None = None) -> int:
    """Replace this process with the executable; returns only on failure."""
    command = resolve(package, executable) + list(argv)
    if prefix:
        command = shlex.split(prefix) + command
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        os.execvp(command[0], command)
    except OSError as exc:
        raise CliError(f"Failed to run '{command[0]}': {exc.strerror}") from None
    return 1  # not reached
