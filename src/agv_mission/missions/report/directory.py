"""A run directory's whole life, as every front door (``run``, ``regress``, the service's
worker, ``barn``) lives it: the mission written into it, the run, every output."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.report.outputs import open_run_dir, write_mission, write_run
from agv_mission.missions.run.observe import RunControl, RunObserver
from agv_mission.missions.run.record import RunRecord
from agv_mission.missions.run.runner import ProgressCallback, run_mission


@dataclass(frozen=True)
class FinishedRun:
    """A run directory once its run has ended and its outputs are written."""

    run_dir: Path
    record: RunRecord
    result: dict[str, Any]  # the document result.json holds


class ResultNotWritten(Exception):
    """``result.json`` itself could not be written; the message names the file and why."""


def run_under(
    root: Path,
    loaded: LoadedMission,
    name: str | None = None,
    *,
    progress: ProgressCallback | None = None,
    observers: Sequence[RunObserver] = (),
    control: RunControl | None = None,
) -> FinishedRun:
    """Run ``loaded`` in a new run directory under ``root`` (:func:`open_run_dir`, which
    raises :class:`RunDirError` when it cannot be made), then write its outputs."""
    run_dir = open_run_dir(root, loaded, name)
    return _run_and_write(run_dir, loaded, progress, observers, control)


def run_in(
    run_dir: Path,
    loaded: LoadedMission,
    *,
    progress: ProgressCallback | None = None,
    observers: Sequence[RunObserver] = (),
    control: RunControl | None = None,
) -> FinishedRun:
    """Run ``loaded`` in ``run_dir``, a directory its front door made (the service's
    keeps the mission's uploaded files): ``mission.yaml`` first, then the run, then every
    output."""
    write_mission(run_dir, loaded)
    return _run_and_write(run_dir, loaded, progress, observers, control)


def _run_and_write(
    run_dir: Path,
    loaded: LoadedMission,
    progress: ProgressCallback | None,
    observers: Sequence[RunObserver],
    control: RunControl | None,
) -> FinishedRun:
    record = run_mission(loaded, run_dir, progress, observers=observers, control=control)
    try:
        result = write_run(run_dir, loaded, record)
    except Exception as exc:
        raise ResultNotWritten(f"cannot write {run_dir / 'result.json'}: {exc}") from exc
    return FinishedRun(run_dir, record, result)
