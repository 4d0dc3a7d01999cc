"""Where BARN's worlds run: in this process, in a local pool of worker processes (forked
from a server that imported the stack once: a world starts in milliseconds), or on Ray, as
``regress`` runs scenarios (both through :mod:`agv_mission.job_pool`). A cluster's workers
see none of our files: each job then carries its world file and brings its run directory
back."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from agv_mission import job_pool
from agv_mission.barn.suite import BarnInputError, failed_result, run_world, unpack
from agv_mission.job_pool import JobKind, ResultCallback, StopControl
from agv_mission.missions.run.workers import forkserver_context


def _run_world(job: dict[str, Any]) -> dict[str, Any]:
    return run_world(job, StopControl("barn stopped (Ctrl-C)"))


def _fork_context() -> Any:
    return forkserver_context(__name__)


def _order(result: dict[str, Any]) -> int:
    return result["world"]


def _ship(jobs: Sequence[dict[str, Any]]) -> tuple[list[dict[str, Any]], None]:
    """Each job with its world file's bytes."""
    return [{**j, "world_bytes": Path(j["world_file"]).read_bytes()} for j in jobs], None


#: A BARN world, as the job pool runs it.
WORLD_RUN = JobKind(
    run=_run_world,
    failed=failed_result,
    order=_order,
    error=BarnInputError,
    fork_context=_fork_context,
    ship=_ship,
    unpack=unpack,
    noun="world(s)",
)


def warm_up(backend: str, workers: int) -> None:
    """Start the local pool's fork server now, so it imports the stack while we plan."""
    job_pool.warm_up(WORLD_RUN, backend, workers)


def run_worlds(
    jobs: Sequence[dict[str, Any]],
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    on_result: ResultCallback | None = None,
) -> list[dict[str, Any]]:
    """Every job's result, in world order (:class:`~agv_mission.job_pool.Interrupted`
    after Ctrl-C)."""
    return job_pool.run_jobs(WORLD_RUN, jobs, backend, workers, address, on_result)
