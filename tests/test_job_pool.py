"""The job pool regress and barn run on: results in order, a Ctrl-C that stops the queue,
an unknown backend refused (the process pool and Ray are driven by test_regress.py and
test_barn.py)."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

import pytest

from agv_mission import job_pool
from agv_mission.job_pool import Interrupted, JobKind, StopControl


class _Refused(ValueError):
    pass


def _square(job: dict[str, Any]) -> dict[str, Any]:
    if job.get("interrupt"):  # what Ctrl-C does while this job runs
        os.kill(os.getpid(), signal.SIGINT)
    return {"n": job["n"], "square": job["n"] ** 2}


def _failed(job: dict[str, Any], error: str) -> dict[str, Any]:
    return {"n": job["n"], "error": error}


def _order(result: dict[str, Any]) -> int:
    return result["n"]


def _no_fork() -> Any:
    raise AssertionError("one worker runs in this process")


def _ship(jobs: Any) -> tuple[list[dict[str, Any]], None]:
    return list(jobs), None


def _unpack(result: dict[str, Any], _root: Path) -> dict[str, Any]:
    return result


SQUARES = JobKind(_square, _failed, _order, _Refused, _no_fork, _ship, _unpack, "square(s)")


def test_results_come_back_in_the_kinds_order_and_each_is_reported() -> None:
    seen: list[tuple[int, int, int]] = []
    jobs = [{"n": 3}, {"n": 1}, {"n": 2}]
    results = job_pool.run_jobs(
        SQUARES, jobs, on_result=lambda r, done, total: seen.append((r["n"], done, total))
    )
    assert [r["square"] for r in results] == [1, 4, 9]
    assert seen == [(3, 1, 3), (1, 2, 3), (2, 3, 3)]  # as they finished


def test_ctrl_c_ends_the_queue_and_reports_what_ran() -> None:
    before = signal.getsignal(signal.SIGINT)
    jobs = [{"n": 1}, {"n": 2, "interrupt": True}, {"n": 3}]
    with pytest.raises(Interrupted, match="after 2 square") as caught:
        job_pool.run_jobs(SQUARES, jobs)
    assert [r["n"] for r in caught.value.results] == [1, 2]  # the third never started
    assert signal.getsignal(signal.SIGINT) is before  # the caller's handler is back


def test_a_stop_request_cancels_the_running_mission_with_the_front_doors_reason() -> None:
    class Run:
        reason: str | None = None

        def cancel(self, reason: str) -> None:
            self.reason = reason

    control, run = StopControl("regress stopped (Ctrl-C)"), Run()
    job_pool._STOP.clear()
    control.before_step(run)
    assert run.reason is None
    job_pool._request_stop(signal.SIGTERM, None)
    try:
        control.before_step(run)
    finally:
        job_pool._STOP.clear()
    assert run.reason == "regress stopped (Ctrl-C)"


def test_an_unknown_backend_is_refused_with_the_kinds_error() -> None:
    with pytest.raises(_Refused, match="unknown backend 'slurm'"):
        job_pool.run_jobs(SQUARES, [{"n": 1}], backend="slurm")
