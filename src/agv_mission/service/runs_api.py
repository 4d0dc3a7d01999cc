"""The runs resource of the API: submit, list, read, validate, and steer a run (cancel,
pause, resume, goal, room records)."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from agv_mission.service.bodies import mission_input, read_body, submission
from agv_mission.service.bodies import validate as validate_mission
from agv_mission.service.context import ApiError, Service
from agv_mission.service.registry import FINAL, STATUSES
from agv_mission.service.runs import NotActive, QueueFull

MAX_LABEL = 100


def runs_router(service: Service) -> APIRouter:
    """``/api/runs`` and ``/api/validate`` for one service."""
    router = APIRouter()
    manager, registry = service.manager, service.registry

    def with_live(run: dict[str, Any]) -> dict[str, Any]:
        """A registry row with what only the running worker knows yet: progress, and a
        status it changed a moment ago (paused, resumed)."""
        live = manager.live_progress(run["id"])
        if live is not None:
            run["progress"] = live
        if run["id"] in manager.active:
            run["status"] = manager.active[run["id"]].status
        return run

    async def run_object(run: dict[str, Any]) -> dict[str, Any]:
        with_live(run)
        if run["status"] in FINAL:
            run["result"] = await manager.results.get(run["id"])
        return run

    @router.post("/api/runs", status_code=201)
    async def submit(request: Request) -> JSONResponse:
        try:
            manager.check_room()
            sub = await submission(service, request)
            run = await manager.submit(sub)
        except QueueFull as exc:
            raise ApiError(429, str(exc)) from None
        return JSONResponse(run, status_code=201)

    @router.post("/api/validate")
    async def validate_route(request: Request) -> dict[str, Any]:
        text, sets, seed = await mission_input(request)
        loaded = await asyncio.to_thread(validate_mission, service, text, sets, seed)
        return {"ok": True, "mission": loaded.resolved()}

    @router.get("/api/runs")
    async def list_runs(status: str | None = None, limit: int = 100) -> dict[str, Any]:
        if status is not None and status not in STATUSES:
            raise ApiError(422, f"unknown status {status!r}; one of {sorted(STATUSES)}")
        if not 1 <= limit <= 1000:
            raise ApiError(422, "limit must be between 1 and 1000")
        return {"runs": [with_live(run) for run in await registry.alist(status, limit)]}

    @router.get("/api/runs/{run_id}")
    async def one_run(run_id: str) -> dict[str, Any]:
        return await run_object(await service.get_run(run_id))

    def control(run_id: str, act: Callable[[str], None], status: str) -> dict[str, Any]:
        """Ask the run's worker to act; 409 when the run is not in a state to."""
        try:
            act(run_id)
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        return {"id": run_id, "status": status}

    @router.post("/api/runs/{run_id}/cancel", status_code=202)
    async def cancel(run_id: str) -> dict[str, Any]:
        run = await service.get_run(run_id)
        if run["status"] in FINAL:
            raise ApiError(409, f"the run is already {run['status']}")
        return control(run_id, manager.cancel, "cancelling")

    @router.post("/api/runs/{run_id}/pause", status_code=202)
    async def pause(run_id: str) -> dict[str, Any]:
        await service.get_run(run_id)
        return control(run_id, manager.pause, "paused")

    @router.post("/api/runs/{run_id}/resume", status_code=202)
    async def resume(run_id: str) -> dict[str, Any]:
        await service.get_run(run_id)
        return control(run_id, manager.resume, "running")

    @router.post("/api/runs/{run_id}/goal", status_code=202)
    async def goal(run_id: str, request: Request) -> dict[str, Any]:
        await service.get_run(run_id)
        body = await read_body(request)
        try:
            doc = json.loads(body)
            x, y = float(doc["x"]), float(doc["y"])
            yaw = float(doc.get("yaw", 0.0))
        except (ValueError, TypeError, KeyError, AttributeError):
            raise ApiError(422, 'the body is {"x": m, "y": m, "yaw": rad}') from None
        if not all(math.isfinite(v) for v in (x, y, yaw)):
            raise ApiError(422, "x, y and yaw must be finite numbers")
        try:
            manager.goal(run_id, x, y, yaw)
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        return {"id": run_id, "goal": {"x": x, "y": y, "yaw": yaw}}

    @router.post("/api/runs/{run_id}/rooms/{label}")
    async def record_room(run_id: str, label: str) -> JSONResponse:
        await service.get_run(run_id)
        label = label.strip()
        if not label or len(label) > MAX_LABEL or not label.isprintable():
            raise ApiError(422, f"a room label is 1 to {MAX_LABEL} printable characters")
        try:
            code, body = await manager.record_room(run_id, label)
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        except asyncio.TimeoutError:
            raise ApiError(503, "the run did not answer in time") from None
        return JSONResponse(body, status_code=code)

    return router
