"""Entry point of the ``ros2`` command (console script ``ros2``).

If a real ros2cli is importable, this hands over to it unchanged, so a full
ROS 2 installation is never shadowed. Otherwise it dispatches to the verbs of
this package. Exit code 0 on success; on failure one line on stderr and 1 (or
the exit code of the executable for ``ros2 run``).
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from collections.abc import Sequence

from tank_control import cli_examples
from tank_control.ros2cli import daemon, node, param, run, service, topic
from tank_control.ros2cli import common
from tank_control.ros2cli.common import DEFAULT_TIMEOUT, CliError

_COMMANDS = (run, param, topic, node, service, daemon)


def real_ros2cli_available() -> bool:
    """True when the ros2cli package (a full ROS 2 install) is importable."""
    try:
        return importlib.util.find_spec('ros2cli') is not None
    except (ImportError, ValueError):
        return False


def hand_over() -> int:
    """Run ros2cli's own entry point (``ros2cli.cli:main``) with our argv."""
    from ros2cli.cli import main as ros2cli_main
    return ros2cli_main()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='ros2', formatter_class=argparse.RawDescriptionHelpFormatter,
        description='ros2 is an extensible command-line tool for ROS 2 '
                    '(tank_control edition: run, param, topic, node, service, daemon).')
    commands = parser.add_subparsers(
        title='Commands', dest='command',
        metavar='Call `ros2 <command> -h` for more detailed usage.')
    commands.required = True
    for module in _COMMANDS:
        module.add_parser(commands)
    return cli_examples.attach(parser)


def run_cli(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` and run the verb; errors become one line on stderr and exit 1."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if run.is_run_command(argv):
        # `ros2 run PKG EXE ...`: everything after EXE belongs to the executable.
        return _guarded(lambda: run.main_from_argv(argv[1:]))
    args = parser.parse_args(argv)
    if daemon.wanted(args) and common.DAEMON is None:
        try:
            forwarded = daemon.forward(argv, _answer_wait(args), read_only=args.verb != 'set')
        except CliError as exc:
            print(str(exc), file=sys.stderr)
            return 1
        if forwarded is not None:
            return forwarded
    return _guarded(lambda: args.func(args))


def _answer_wait(args: argparse.Namespace) -> float:
    """Longest wait [s] for the daemon's answer: the verb's own waits (a set asks the
    node three times), with margin for a loaded machine."""
    return 4 * float(getattr(args, 'timeout', DEFAULT_TIMEOUT)) + 30.0


def _guarded(call) -> int:
    try:
        rc = call()
    except BrokenPipeError as exc:
        # the reader went away (`ros2 topic echo /measurement | head`): stop quietly, as cat
        # does; stdout goes to /dev/null so that the exit's flush raises nothing more
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return common.exit_status(exc)
    except (Exception, KeyboardInterrupt) as exc:   # CliError, a requested stop, the unforeseen
        line = common.failure_line(exc)
        if line:
            print(line, file=sys.stderr)
        return common.exit_status(exc)
    return 0 if rc is None else rc


def main(argv: Sequence[str] | None = None) -> int:
    if real_ros2cli_available():
        return hand_over()
    common.GUARD_TEARDOWN = True
    return run_cli(argv)


if __name__ == '__main__':
    sys.exit(main())
