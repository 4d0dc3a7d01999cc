"""``agv-mission ARGS`` called in the test's own process, through the program's own typer
app: the same parsing, messages on stdout/stderr and exit codes, without the two seconds a
fresh interpreter spends importing. The way in as a process (``python -m agv_mission.cli``,
the ``agv-mission`` script, Ctrl-C, a closed pipe) stays covered by tests that start one
(test_cli.py, test_failures.py, test_bounds.py); the tests that use this call check
what a command says and returns for a given input."""

from __future__ import annotations

import contextlib
import signal
import subprocess
from pathlib import Path

from typer.testing import CliRunner

from agv_mission.cli import app


def agv(
    *args: str, cwd: Path | None = None, input: str | None = None
) -> subprocess.CompletedProcess[str]:
    """Run ``agv-mission *args`` here; its exit code, stdout and stderr as a finished
    process. An exception the program lets escape fails the test (as the traceback would).
    The signal handlers a command installs (``run``'s SignalStop) are put back after it."""
    runner = CliRunner()
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    where = contextlib.chdir(cwd) if cwd is not None else contextlib.nullcontext()
    try:
        with where:
            result = runner.invoke(app, list(args), input=input, catch_exceptions=False)
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    return subprocess.CompletedProcess(
        ["agv-mission", *args], result.exit_code, result.stdout, result.stderr
    )
