"""What a run produced, as files and words.

Owns the run directory (``result.json``, ``trajectory.csv``, plots, the mission as it
ran: :func:`open_run_dir`, :func:`write_run`; its whole life, the mission written, run
and its outputs written: :func:`run_under`, :func:`run_in`), the one-line and table
summaries the front doors print, the scenario expectations (``expect:``) checked against
a result, and the robots' colours. It reads a finished ``RunRecord``, never a live run.

The names below load on first use.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "open_run_dir": "outputs",
    "write_run": "outputs",
    "write_mission": "outputs",
    "RunDirError": "outputs",
    "run_under": "directory",
    "run_in": "directory",
    "FinishedRun": "directory",
    "ResultNotWritten": "directory",
    "check": "expectations",
    "Failure": "expectations",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{module}"), name)
