"""Processes on this machine as /proc lists them: by command line, by process group."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path


def _entries() -> Iterator[Path]:
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            yield entry


def processes_with(text: str) -> list[int]:
    """Pids of the processes whose command line (arguments joined by spaces) contains
    ``text``."""
    pids = []
    for entry in _entries():
        try:
            cmdline = (entry / 'cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace')
        except OSError:                 # ended meanwhile
            continue
        if text in cmdline:
            pids.append(int(entry.name))
    return pids


def group_members(pgid: int) -> list[int]:
    """Pids of the live (not zombie) processes in process group ``pgid``."""
    members = []
    for entry in _entries():
        try:
            fields = (entry / 'stat').read_bytes().rsplit(b')', 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] != b'Z':   # state, ppid, pgrp; zombies ended
            members.append(int(entry.name))
    return members
