"""Regress backends: run jobs (plain dicts in, plain dicts out) in a local process pool
or on Ray, and one job in this process."""

from __future__ import annotations

import io
import json
import os
import shutil
import tarfile
import tempfile
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from agv_mission import job_pool
from agv_mission.job_pool import JobKind, ResultCallback, StopControl
from agv_mission.json_values import json_default
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.run.workers import forkserver_context
from agv_mission.regress.plan import RegressError, sweep_overrides


def run_job(job: dict[str, Any]) -> dict[str, Any]:
    """Run one job (load, run, write the run directory, check); a plain dict back.

    Never raises: an exception becomes a result with status ``error``.
    """
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.report.directory import run_under
    from agv_mission.missions.report.expectations import check

    t0 = time.perf_counter()
    shipped = bool(job.get("ship_back"))  # on a remote worker: the run directory comes back
    output_root = Path(tempfile.mkdtemp(prefix="agv-regress-")) if shipped else None
    try:
        loaded = load_mission(job["scenario"], sweep_overrides(job["overrides"]), job["seed"])
        done = run_under(
            output_root or Path(job["output_root"]),
            loaded,
            job["run_name"],
            control=StopControl("regress stopped (Ctrl-C)"),
        )
        run_dir = done.run_dir
        doc = json.loads(json.dumps(done.result, default=json_default))  # plain types only
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


def _fork_context() -> Any:
    return forkserver_context(__name__)


def _order(result: dict[str, Any]) -> tuple[int, ...]:
    return tuple(result["order"])


def _ship_to_cluster(
    jobs: Sequence[dict[str, Any]],
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    working_dir, shipped = _ship(jobs)
    return shipped, {"working_dir": working_dir}


#: A scenario run, as the job pool runs it.
SCENARIO_RUN = JobKind(
    run=run_job,
    failed=error_result,
    order=_order,
    error=RegressError,
    fork_context=_fork_context,
    ship=_ship_to_cluster,
    unpack=_unpack,
    noun="run(s)",
)


def warm_up(backend: str = "local", workers: int | None = None) -> None:
    """Start the local pool's fork server now, so that it imports the stack while this
    process plans (call before :func:`plan_jobs`; harmless otherwise)."""
    job_pool.warm_up(SCENARIO_RUN, backend, workers or os.cpu_count() or 1)


def run_jobs(
    jobs: Sequence[dict[str, Any]],
    backend: str = "local",
    workers: int | None = None,
    address: str | None = None,
    on_result: ResultCallback | None = None,
) -> list[dict[str, Any]]:
    """Run every job on ``backend``; results in the order of the plan (scenario, variant,
    seed), whatever order they finished in (:class:`~agv_mission.job_pool.Interrupted` after Ctrl-C)."""
    workers = max(1, workers or os.cpu_count() or 1)
    return job_pool.run_jobs(SCENARIO_RUN, jobs, backend, workers, address, on_result)
