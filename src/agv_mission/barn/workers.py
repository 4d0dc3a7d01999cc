"""Where BARN's worlds run: in this process, in a local pool of worker processes (forked
from a server that imported the stack once: a world starts in milliseconds), or on Ray, as
``regress`` runs scenarios. A cluster's workers see none of our files: each job then
carries its world file and brings its run directory back."""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

from agv_mission.barn.suite import BarnInputError, failed_result, run_world, unpack
from agv_mission.missions.run.workers import forkserver_context

ResultCallback = Callable[[dict[str, Any], int, int], None]

# Signals this process was asked to stop with: the running worlds end ``aborted`` before
# their next step (a failed world), the queued ones do not start.
_STOP: list[int] = []


def _request_stop(signum: int, _frame: object) -> None:
    _STOP.append(signum)


def _stop_on_signals() -> None:
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)


class _StopControl:
    """Ends a run ``aborted`` once a stop was requested."""

    only_cancels = True

    def before_step(self, run: Any) -> None:
        if _STOP:
            run.cancel("barn stopped (Ctrl-C)")


class Interrupted(Exception):
    """Stopped: ``results`` holds the worlds that ran."""

    def __init__(self, results: list[dict[str, Any]]) -> None:
        super().__init__(f"interrupted after {len(results)} world(s)")
        self.results = results


def _job(job: dict[str, Any]) -> dict[str, Any] | None:
    """A worker's job: None when a stop came before it began."""
    if _STOP:
        return None
    return run_world(job, _StopControl())


def warm_up(backend: str, workers: int) -> None:
    """Start the local pool's fork server now, so it imports the stack while we plan."""
    if backend == "local" and workers > 1:
        from multiprocessing import forkserver

        forkserver_context("agv_mission.barn.workers")
        forkserver.ensure_running()


def run_worlds(
    jobs: Sequence[dict[str, Any]],
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    on_result: ResultCallback | None = None,
) -> list[dict[str, Any]]:
    """Every job's result, in world order."""
    results: list[dict[str, Any]] = []

    def collect(result: dict[str, Any] | None) -> None:
        if result is None:
            return
        results.append(result)
        if on_result is not None:
            on_result(result, len(results), len(jobs))

    _STOP.clear()
    previous = signal.signal(signal.SIGINT, _request_stop)
    try:
        if backend == "local":
            _run_local(jobs, workers, collect)
        elif backend == "ray":
            _run_ray(jobs, workers, address, collect)
        else:
            raise BarnInputError(f"--backend {backend}: local or ray")
    finally:
        signal.signal(signal.SIGINT, previous)
    ordered = sorted(results, key=lambda r: r["world"])
    if _STOP:
        raise Interrupted(ordered)
    return ordered


def _run_local(jobs: Sequence[dict[str, Any]], workers: int, collect: Callable) -> None:
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            if _STOP:
                break
            collect(_job(job))
        return
    with ProcessPoolExecutor(
        max_workers=min(workers, len(jobs)),
        mp_context=forkserver_context("agv_mission.barn.workers"),
        initializer=_stop_on_signals,
    ) as pool:
        futures = {pool.submit(_job, job): job for job in jobs}
        pending = set(futures)
        stopping = False
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            for future in done:
                if future.cancelled():
                    continue
                try:
                    result = future.result()
                except Exception as exc:  # a worker died (killed, out of memory)
                    result = failed_result(futures[future], f"worker process failed: {exc!r}")
                collect(result)
            if _STOP and not stopping:
                stopping = True
                for future in pending:
                    future.cancel()
                for process in list(getattr(pool, "_processes", {}).values()):
                    with contextlib.suppress(OSError):
                        os.kill(process.pid, signal.SIGINT)


def _run_ray(
    jobs: Sequence[dict[str, Any]], workers: int, address: str | None, collect: Callable
) -> None:
    try:
        import ray
    except ImportError:
        raise BarnInputError(
            "the ray backend needs Ray, which is not installed: pip install 'agv-mission[ray]'"
        ) from None
    if address:  # a cluster: send each world with its job, bring each run directory back
        output_root = Path(jobs[0]["output_root"]) if jobs else Path(".")
        jobs = [{**j, "world_bytes": Path(j["world_file"]).read_bytes()} for j in jobs]
        inner = collect

        def collect(result: dict[str, Any] | None) -> None:
            inner(unpack(result, output_root) if result is not None else None)

    started = False
    if not ray.is_initialized():
        options: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
        if address:
            options["address"] = address
        else:  # a new local instance, never a cluster that happens to run here
            options["address"] = "local"
            options["num_cpus"] = workers
        try:
            ray.init(**options)
        except Exception as exc:
            raise BarnInputError(
                f"cannot start or reach Ray ({address or 'local'}): {exc}"
            ) from None
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(run_world)
        pending = {task.remote(job): job for job in jobs}
        cancelled = False
        while pending:
            if _STOP and not cancelled:
                cancelled = True
                for ref in pending:
                    ray.cancel(ref)
            done, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
            for ref in done:
                job = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.TaskCancelledError:
                    result = None
                except Exception as exc:
                    result = failed_result(job, f"ray task failed: {exc!r}")
                collect(result)
    finally:
        if started:
            ray.shutdown()
