"""Regress backends: run jobs (plain dicts in, plain dicts out) in a local process pool
or on Ray, and one job in this process."""

from __future__ import annotations

import json
import multiprocessing
import os
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

from agv_mission.missions.errors import MissionError
from agv_mission.regress.plan import RegressError, ResultCallback
from agv_mission.regress.report import json_default


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """Run one job (load, run, write the run directory, check); a plain dict back.

    Never raises: an exception becomes a result with status ``error``.
    """
    from agv_mission.missions.expectations import check
    from agv_mission.missions.loader import load_mission
    from agv_mission.missions.outputs import make_run_dir, write_mission, write_run
    from agv_mission.missions.runner import run_mission

    t0 = time.perf_counter()
    try:
        loaded = load_mission(job["scenario"], job["overrides"], job["seed"])
        run_dir = make_run_dir(Path(job["output_root"]), job["run_name"])
        write_mission(run_dir, loaded)
        record = run_mission(loaded, run_dir)
        doc = write_run(run_dir, loaded, record)
        doc = json.loads(json.dumps(doc, default=json_default))  # plain types only
        failures = [f.to_dict() for f in check(loaded.mission.expect, doc)]
    except MissionError as exc:
        return error_result(job, "invalid input:\n" + "\n".join(map(str, exc.problems)))
    except Exception:
        return error_result(job, traceback.format_exc())
    return {
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


WORKER_PRELOAD = [
    "agv_mission.regress.backends",
    "agv_mission.missions.loader",
    "agv_mission.missions.runner",
    "agv_mission.missions.outputs",
    "matplotlib",
]


def _pool_context() -> Any:
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(WORKER_PRELOAD)
    return ctx


def warm_up(backend: str = "local", workers: int | None = None) -> None:
    """Start the local pool's fork server now, so that it imports the stack while this
    process plans (call before :func:`plan_jobs`; harmless otherwise)."""
    if backend == "local" and (workers or os.cpu_count() or 1) > 1:
        from multiprocessing import forkserver

        _pool_context()
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

    def collect(result: dict[str, Any]) -> None:
        results.append(result)
        if on_result is not None:
            on_result(result, len(results), len(jobs))

    if backend == "local":
        _run_local(jobs, workers, collect)
    elif backend == "ray":
        _run_ray(jobs, workers, address, collect)
    else:
        raise RegressError(f"unknown backend {backend!r} (local or ray)")
    return sorted(results, key=lambda r: tuple(r["order"]))


def _run_local(jobs: Sequence[dict[str, Any]], workers: int, collect: Callable) -> None:
    if workers == 1 or len(jobs) <= 1:
        for job in jobs:
            collect(run_job(job))
        return
    with ProcessPoolExecutor(
        max_workers=min(workers, len(jobs)), mp_context=_pool_context()
    ) as pool:
        futures = {pool.submit(run_job, job): job for job in jobs}
        for future in as_completed(futures):
            try:
                result = future.result()
            except Exception as exc:  # a worker died (killed, out of memory, ...)
                result = error_result(futures[future], f"worker process failed: {exc!r}")
            collect(result)


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
    if not ray.is_initialized():
        options: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING"}
        if address:
            options["address"] = address
        else:
            options["num_cpus"] = workers
        try:
            ray.init(**options)
        except Exception as exc:
            raise RegressError(f"cannot start or reach Ray ({address or 'local'}): {exc}") from None
        started = True
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(run_job)
        pending = {task.remote(job): job for job in jobs}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as exc:
                    result = error_result(job, f"ray task failed: {exc!r}")
                collect(result)
    finally:
        if started:
            ray.shutdown()


# ------------------------------------------------------------------------------- results
