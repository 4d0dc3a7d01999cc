"""Regress backends: run jobs (plain dicts in, plain dicts out) in a local process pool
or on Ray, and one job in this process."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
import tarfile
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path
from typing import Any

from agv_mission.messages import json_default
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.run.workers import forkserver_context
from agv_mission.regress.plan import RegressError, ResultCallback, sweep_overrides

# Signals this process was asked to stop with (Ctrl-C, SIGTERM): a run in progress ends
# ``aborted`` before its next step, a job not started yet is not started.
_STOP: list[int] = []


def _request_stop(signum: int, _frame: object) -> None:
    _STOP.append(signum)


def _stop_on_signals() -> None:
    """Pool worker start: SIGINT/SIGTERM ask the running job to stop (see ``_STOP``)."""
    signal.signal(signal.SIGINT, _request_stop)
    signal.signal(signal.SIGTERM, _request_stop)


class _StopControl:
    """The run-control hook that ends a run ``aborted`` once a stop was requested."""

    only_cancels = True  # robots may decide in other processes (missions.run.team)

    def before_step(self, run: Any) -> None:
        if _STOP:
            run.cancel("regress stopped (Ctrl-C)")


class Interrupted(Exception):
    """``run_jobs`` was stopped: ``results`` holds the jobs that ran (the running ones
    ended ``aborted``); queued jobs were cancelled."""

    def __init__(self, results: list[dict[str, Any]]) -> None:
        super().__init__(f"interrupted after {len(results)} run(s)")
        self.results = results


def run_job(job: dict[str, Any]) -> dict[str, Any] | None:
    """Run one job (load, run, write the run directory, check); a plain dict back.

    Never raises: an exception becomes a result with status ``error``. None: a stop was
    requested before the job began, so it did not run.
    """
    if _STOP:
        return None
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.report.expectations import check
    from agv_mission.missions.report.outputs import open_run_dir, write_run
    from agv_mission.missions.run.runner import run_mission

    t0 = time.perf_counter()
    shipped = bool(job.get("ship_back"))  # on a remote worker: the run directory comes back
    output_root = Path(tempfile.mkdtemp(prefix="agv-regress-")) if shipped else None
    try:
        loaded = load_mission(job["scenario"], sweep_overrides(job["overrides"]), job["seed"])
        run_dir = open_run_dir(output_root or Path(job["output_root"]), loaded, job["run_name"])
        record = run_mission(loaded, run_dir, control=_StopControl())
        doc = write_run(run_dir, loaded, record)
        doc = json.loads(json.dumps(doc, default=json_default))  # plain types only
        failures = [f.to_dict() for f in check(loaded.mission.expect, doc)]
    except MissionError as exc:
        return error_result(job, "invalid input:\n" + "\n".join(map(str, exc.problems)))
    except Exception:
        return error_result(job, traceback.format_exc())
    result = {
        **_job_keys(job),
        "status": doc["status"],
        "reason": doc["reason"],
        "sim_time": doc["sim_time"],
        "wall_time": round(time.perf_counter() - t0, 3),
        "run_dir": doc["run_dir"],
        "metrics": doc["metrics"],
        "tasks": doc["tasks"],
        "rooms_recorded": sorted(doc.get("rooms_recorded") or {}),
        "failures": failures,
        "passed": not failures,
        "error": None,
    }
    if shipped:
        result["archive"] = _pack(run_dir)
        shutil.rmtree(output_root, ignore_errors=True)
    return result


def _pack(run_dir: Path) -> bytes:
    """The run directory as a gzipped tar (its name as the top folder)."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        tar.add(run_dir, arcname=run_dir.name)
    return buf.getvalue()


def _unpack(result: dict[str, Any], output_root: Path) -> dict[str, Any]:
    """Extract a shipped run directory under ``output_root``; the result points there."""
    archive = result.pop("archive", None)
    if archive is None:
        return result
    output_root.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        names = tar.getnames()
        tar.extractall(output_root, filter="data")
    top = names[0].split("/")[0] if names else None
    if top is not None:
        result["run_dir"] = str(output_root / top)
    return result


def _ship(jobs: Sequence[dict[str, Any]]) -> tuple[str, list[dict[str, Any]]]:
    """The folder to send to remote workers (Ray's ``working_dir``: every scenario and the
    files next to it that it names) and the jobs rewritten to paths inside it."""
    folders = [str(Path(j["scenario"]).resolve().parent) for j in jobs]
    root = Path(os.path.commonpath(folders))
    size = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    if root == Path(root.anchor) or size > SHIP_LIMIT:
        raise RegressError(
            f"the scenarios share the folder {root} ({size / 1e6:.0f} MB): to send them to a "
            f"Ray cluster, put them under one folder of at most {SHIP_LIMIT / 1e6:.0f} MB"
        )
    shipped = [
        {
            **j,
            "scenario": str(Path(j["scenario"]).resolve().relative_to(root)),
            "ship_back": True,
        }
        for j in jobs
    ]
    return str(root), shipped


SHIP_LIMIT = 50_000_000  # bytes of scenario folder sent to a Ray cluster


def error_result(job: dict[str, Any], error: str) -> dict[str, Any]:
    """The result of a job that could not run to its end."""
    return {
        **_job_keys(job),
        "status": "error",
        "reason": error.strip().splitlines()[-1] if error.strip() else "error",
        "sim_time": None,
        "wall_time": None,
        "run_dir": None,
        "metrics": {},
        "tasks": [],
        "rooms_recorded": [],
        "failures": [],
        "passed": False,
        "error": error,
    }


def _job_keys(job: dict[str, Any]) -> dict[str, Any]:
    keys = ("id", "order", "scenario", "name", "variant", "overrides", "seed")
    return {k: job[k] for k in keys}


# ------------------------------------------------------------------------------ backends


def warm_up(backend: str = "local", workers: int | None = None) -> None:
    """Start the local pool's fork server now, so that it imports the stack while this
    process plans (call before :func:`plan_jobs`; harmless otherwise)."""
    if backend == "local" and (workers or os.cpu_count() or 1) > 1:
        from multiprocessing import forkserver

        forkserver_context("agv_mission.regress.backends")
        forkserver.ensure_running()


def run_jobs(
    jobs: Sequence[dict[str, Any]],
    backend: str = "local",
    workers: int | None = None,
    address: str | None = None,
    on_result: ResultCallback | None = None,
) -> list[dict[str, Any]]:
    """Run every job on ``backend``; results in the order of the plan (scenario, variant,
    seed), whatever order they finished in."""
    workers = max(1, workers or os.cpu_count() or 1)
    results: list[dict[str, Any]] = []

    def collect(result: dict[str, Any] | None) -> None:
        if result is None:  # cancelled before it began
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
            raise RegressError(f"unknown backend {backend!r} (local or ray)")
    finally:
        signal.signal(signal.SIGINT, previous)
    ordered = sorted(results, key=lambda r: tuple(r["order"]))
    if _STOP:
        raise Interrupted(ordered)
    return ordered


def _run_local(jobs: Sequence[dict[str, Any]], workers: int, collect: Callable) -> None:
    """In this process (one worker) or a process pool. A stop request (``_STOP``, set by
    the SIGINT handler) cancels the queued jobs and asks the workers to end theirs."""
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            if _STOP:
                break
            collect(run_job(job))
        return
    with ProcessPoolExecutor(
        max_workers=min(workers, len(jobs)),
        mp_context=forkserver_context("agv_mission.regress.backends"),
        initializer=_stop_on_signals,
    ) as pool:
        futures = {pool.submit(run_job, job): job for job in jobs}
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
                    result = error_result(futures[future], f"worker process failed: {exc!r}")
                collect(result)
            if _STOP and not stopping:
                stopping = True
                for future in pending:
                    future.cancel()
                for process in list(getattr(pool, "_processes", {}).values()):
                    with contextlib.suppress(OSError):
                        os.kill(process.pid, signal.SIGINT)  # the worker ends its run


def _run_ray(
    jobs: Sequence[dict[str, Any]], workers: int, address: str | None, collect: Callable
) -> None:
    try:
        import ray
    except ImportError:
        raise RegressError(
            "the ray backend needs Ray, which is not installed: pip install 'agv-mission[ray]'"
        ) from None
    started = False
    if address:  # a cluster: its workers see none of our files, so send them
        working_dir, jobs = _ship(jobs)
        output_root = Path(jobs[0]["output_root"]) if jobs else Path(".")
        inner = collect

        def collect(result: dict[str, Any] | None) -> None:
            inner(_unpack(result, output_root) if result is not None else None)

    if not ray.is_initialized():
        options: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
        if address:
            options["address"] = address
            options["runtime_env"] = {"working_dir": working_dir}
        else:  # a new local instance, never a cluster that happens to run here
            options["address"] = "local"
            options["num_cpus"] = workers
        try:
            ray.init(**options)
        except Exception as exc:
            raise RegressError(f"cannot start or reach Ray ({address or 'local'}): {exc}") from None
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(run_job)
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
                    result = error_result(job, f"ray task failed: {exc!r}")
                collect(result)
    finally:
        if started:
            ray.shutdown()


# ------------------------------------------------------------------------------- results
