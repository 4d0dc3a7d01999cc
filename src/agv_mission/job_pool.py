"""Where the front doors that run many missions (``regress``, ``barn``) run their jobs: in
this process, in a local pool of worker processes, or on Ray.

A job and its result are plain dicts; a :class:`JobKind` says how to run one, what a job
whose worker died gives, how results are ordered and, for a Ray cluster (whose workers see
none of our files), how jobs are sent and their run directories brought back. Ctrl-C or
SIGTERM asks the pool to stop: the running jobs end ``aborted`` before their next step
(their run control is a :class:`StopControl`), the queued ones do not start, and
:class:`Interrupted` carries the results of those that ran.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

Job = dict[str, Any]
Result = dict[str, Any]
ResultCallback = Callable[[Result, int, int], None]

# Signals this process was asked to stop with (Ctrl-C, SIGTERM): a run in progress ends
# ``aborted`` before its next step, a job not started yet is not started.
_STOP: list[int] = []


def _request_stop(signum: int, _frame: object) -> None:
    _STOP.append(signum)


def _stop_on_signals() -> None:
    """Pool worker start: SIGINT/SIGTERM ask the running job to stop (see ``_STOP``)."""
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)


class StopControl:
    """The run-control hook that ends a run ``aborted`` once a stop was requested."""

    only_cancels = True  # robots may decide in other processes (missions.team)

    def __init__(self, reason: str) -> None:
        self.reason = reason

    def before_step(self, run: Any) -> None:
        if _STOP:
            run.cancel(self.reason)


class Interrupted(Exception):
    """The pool was stopped: ``results`` holds the jobs that ran (the running ones ended
    ``aborted``); queued jobs were cancelled."""

    def __init__(self, results: list[Result], noun: str = "job(s)") -> None:
        super().__init__(f"interrupted after {len(results)} {noun}")
        self.results = results


@dataclass(frozen=True)
class JobKind:
    """What the pool needs to know of one kind of job."""

    #: Runs one job, never raising (module level: workers import it by name).
    run: Callable[[Job], Result]
    #: The result of a job whose worker or Ray task failed, with the error's text.
    failed: Callable[[Job, str], Result]
    #: The key results are sorted by, whatever order they finished in.
    order: Callable[[Result], Any]
    #: The exception a bad backend or an unreachable Ray raises.
    error: type[Exception]
    #: The local pool's process context (a fork server that preloaded the stack).
    fork_context: Callable[[], Any]
    #: For a Ray cluster: the jobs as sent, and Ray's ``runtime_env`` (None: none).
    ship: Callable[[Sequence[Job]], tuple[list[Job], dict[str, Any] | None]]
    #: A result of a cluster's worker with its run directory extracted under a folder.
    unpack: Callable[[Result, Path], Result]
    #: What a job is, in :class:`Interrupted`'s message.
    noun: str = "job(s)"


def run_one(run: Callable[[Job], Result], job: Job) -> Result | None:
    """A worker's job: None when a stop came before it began."""
    if _STOP:
        return None
    return run(job)


def warm_up(kind: JobKind, backend: str, workers: int) -> None:
    """Start the local pool's fork server now, so that it imports the stack while the
    caller plans (harmless otherwise)."""
    if backend == "local" and workers > 1:
        from multiprocessing import forkserver

        kind.fork_context()
        forkserver.ensure_running()


def run_jobs(
    kind: JobKind,
    jobs: Sequence[Job],
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    on_result: ResultCallback | None = None,
) -> list[Result]:
    """Every job's result, in ``kind.order``; :class:`Interrupted` after a stop request."""
    results: list[Result] = []

    def collect(result: Result | None) -> None:
        if result is None:  # cancelled before it began
            return
        results.append(result)
        if on_result is not None:
            on_result(result, len(results), len(jobs))

    _STOP.clear()
    previous = signal.signal(signal.SIGINT, _request_stop)
    try:
        if backend == "local":
            _run_local(kind, jobs, workers, collect)
        elif backend == "ray":
            _run_ray(kind, jobs, workers, address, collect)
        else:
            raise kind.error(f"unknown backend {backend!r} (local or ray)")
    finally:
        signal.signal(signal.SIGINT, previous)
    ordered = sorted(results, key=kind.order)
    if _STOP:
        raise Interrupted(ordered, kind.noun)
    return ordered


def _run_local(
    kind: JobKind, jobs: Sequence[Job], workers: int, collect: Callable[[Result | None], None]
) -> None:
    """In this process (one worker) or a process pool. A stop request (``_STOP``, set by
    the SIGINT handler) cancels the queued jobs and asks the workers to end theirs."""
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            if _STOP:
                break
            collect(run_one(kind.run, job))
        return
    with ProcessPoolExecutor(
        max_workers=min(workers, len(jobs)),
        mp_context=kind.fork_context(),
        initializer=_stop_on_signals,
    ) as pool:
        futures = {pool.submit(run_one, kind.run, job): job for job in jobs}
        pending = set(futures)
        stopping = False
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            for future in done:
                if future.cancelled():
                    continue
                try:
                    result = future.result()
                except Exception as exc:  # a worker died (killed, out of memory, ...)
                    result = kind.failed(futures[future], f"worker process failed: {exc!r}")
                collect(result)
            if _STOP and not stopping:
                stopping = True
                for future in pending:
                    future.cancel()
                for process in list(getattr(pool, "_processes", {}).values()):
                    with contextlib.suppress(OSError):
                        os.kill(process.pid, signal.SIGINT)  # the worker ends its run


def _run_ray(
    kind: JobKind,
    jobs: Sequence[Job],
    workers: int,
    address: str | None,
    collect: Callable[[Result | None], None],
) -> None:
    try:
        import ray
    except ImportError:
        raise kind.error(
            "the ray backend needs Ray, which is not installed: pip install 'agv-mission[ray]'"
        ) from None
    runtime_env = None
    if address:  # a cluster: its workers see none of our files, so send them
        jobs, runtime_env = kind.ship(jobs)
        output_root = Path(jobs[0]["output_root"]) if jobs else Path(".")
        inner = collect

        def collect(result: Result | None) -> None:
            inner(kind.unpack(result, output_root) if result is not None else None)

    started = _start_ray(ray, kind, workers, address, runtime_env)
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(kind.run)
        pending = {task.remote(job): job for job in jobs}
        cancelled = False
        while pending:
            if _STOP and not cancelled:
                cancelled = True
                for ref in pending:
                    ray.cancel(ref)  # queued: never starts; running: interrupted (aborted)
            done, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
            for ref in done:
                job = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.TaskCancelledError:
                    result = None  # cancelled by a stop request: did not run
                except Exception as exc:
                    result = kind.failed(job, f"ray task failed: {exc!r}")
                collect(result)
    finally:
        if started:
            ray.shutdown()


def _start_ray(
    ray: Any,
    kind: JobKind,
    workers: int,
    address: str | None,
    runtime_env: dict[str, Any] | None,
) -> bool:
    """Start or join Ray unless it runs already; whether this call started it."""
    if ray.is_initialized():
        return False
    options: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
    if address:
        options["address"] = address
        if runtime_env is not None:
            options["runtime_env"] = runtime_env
    else:  # a new local instance, never a cluster that happens to run here
        options["address"] = "local"
        options["num_cpus"] = workers
    try:
        ray.init(**options)
    except Exception as exc:
        raise kind.error(f"cannot start or reach Ray ({address or 'local'}): {exc}") from None
    return True
