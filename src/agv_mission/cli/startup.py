"""Ctrl-C while the program is still importing: exit 130 quietly, not with a traceback."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

_AS_PROGRAM = [False]  # set once the quiet handler was installed at start


def _exit_quietly(signum: int, _frame: object) -> None:
    os._exit(128 + signum)


def started_as_program() -> bool:
    """Run as ``agv-mission`` or ``python -m agv_mission.cli`` (which imports this package
    while ``sys.argv[0]`` is still ``-m``; by the time a command runs it is the path of
    ``__main__.py``, hence the flag), not imported by a test or a service."""
    return _AS_PROGRAM[0] or sys.argv[0] == "-m" or Path(sys.argv[0]).name == "agv-mission"


def quiet_until_started() -> None:
    """Until a command runs, Ctrl-C exits 130 without a traceback."""
    _AS_PROGRAM[0] = True
    signal.signal(signal.SIGINT, _exit_quietly)


def started() -> None:
    """A command runs: Ctrl-C is Python's KeyboardInterrupt again (each command handles it)."""
    if signal.getsignal(signal.SIGINT) is _exit_quietly:
        signal.signal(signal.SIGINT, signal.default_int_handler)
