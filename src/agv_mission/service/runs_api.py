"""The runs resource of the API: submit, list, read, validate, and steer a run (cancel,
pause, resume, goal, room records)."""

from __future__ import annotations

import asyncio
import shutil
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import JSONResponse
from pydantic import ValidationError

from agv_mission.service.bodies import (
    content_type,
    mission_input,
    problem,
    read_body,
)
from agv_mission.service.bodies import validate as validate_mission
from agv_mission.service.context import ApiError, Service
from agv_mission.service.models import (
    Command,
    Goal,
    GoalSent,
    Pace,
    PaceSet,
    RobotName,
    RoomRecord,
    Run,
    RunList,
    Status,
    Submit,
    SubmitWithFiles,
    Validated,
    answers,
    request_body,
)
from agv_mission.service.registry import FINAL
from agv_mission.service.runs import NotActive, QueueFull, UnknownRobot
from agv_mission.service.uploads import submission

MAX_LABEL = 100


def runs_router(service: Service) -> APIRouter:
    """``/api/runs`` and ``/api/validate`` for one service."""
    router = APIRouter(tags=["runs"])
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

    async def accept(request: Request) -> JSONResponse:
        try:
            manager.check_room()
        except QueueFull as exc:
            raise ApiError(429, str(exc)) from None
        sub, run_id = await submission(service, request)
        try:
            run = await manager.submit(sub, run_id)
        except QueueFull as exc:
            if run_id is not None:  # its files were stored already
                await asyncio.to_thread(shutil.rmtree, registry.run_dir(run_id), True)
            raise ApiError(429, str(exc)) from None
        return JSONResponse(run, status_code=201)

    @router.post(
        "/api/runs",
        status_code=201,
        response_model=Run,
        responses=answers(413, 415, 422, 429),
        openapi_extra=request_body(Submit, yaml=True),
    )
    async def submit(request: Request) -> JSONResponse:
        """Submit a mission: JSON ``{mission, set, seed, pace}`` or the YAML text alone
        (``application/yaml``). A multipart body with the files the mission names is taken
        here too, as at ``POST /api/runs/upload``."""
        return await accept(request)

    @router.post(
        "/api/runs/upload",
        status_code=201,
        response_model=Run,
        responses=answers(413, 415, 422, 429),
        openapi_extra=request_body(SubmitWithFiles, multipart=True),
    )
    async def submit_with_files(request: Request) -> JSONResponse:
        """Submit a mission with the files it names (multipart): the world's map YAML and
        image, rooms, robot and recorder files. They land in the run's own directory
        (``inputs/``), each at its path relative to the mission."""
        if content_type(request) != "multipart/form-data":
            raise ApiError(415, "send multipart/form-data: mission, mission_path, set, seed, files")
        return await accept(request)

    @router.post(
        "/api/validate",
        response_model=Validated,
        responses=answers(413, 415, 422),
        openapi_extra=request_body(Submit, yaml=True),
    )
    async def validate_route(request: Request) -> dict[str, Any]:
        """Validate a mission without running it; the resolved mission."""
        text, sets, seed, _pace = await mission_input(request)
        loaded = await asyncio.to_thread(validate_mission, service, text, sets, seed)
        return {"ok": True, "mission": loaded.resolved()}

    @router.get("/api/runs", response_model=RunList, responses=answers(422))
    async def list_runs(
        status: Status | None = None,
        limit: Annotated[int, Query(ge=1, le=1000, description="at most this many")] = 100,
    ) -> dict[str, Any]:
        """Runs, newest first; ``?status=`` keeps the runs of one status."""
        return {"runs": [with_live(run) for run in await registry.alist(status, limit)]}

    @router.get("/api/runs/{run_id}", response_model=Run, responses=answers(404))
    async def one_run(run_id: str) -> dict[str, Any]:
        """One run; once final, with its ``result``."""
        return await run_object(await service.get_run(run_id))

    def control(run_id: str, act: Callable[[str], None], status: str) -> dict[str, Any]:
        """Ask the run's worker to act; 409 when the run is not in a state to."""
        try:
            act(run_id)
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        return {"id": run_id, "status": status}

    steer = {"status_code": 202, "response_model": Command, "responses": answers(404, 409)}

    @router.post("/api/runs/{run_id}/cancel", **steer)
    async def cancel(run_id: str) -> dict[str, Any]:
        """Stop the run; its final status is ``aborted``."""
        run = await service.get_run(run_id)
        if run["status"] in FINAL:
            raise ApiError(409, f"the run is already {run['status']}")
        return control(run_id, manager.cancel, "cancelling")

    @router.post("/api/runs/{run_id}/pause", **steer)
    async def pause(run_id: str) -> dict[str, Any]:
        """The robot stops and simulated time holds."""
        await service.get_run(run_id)
        return control(run_id, manager.pause, "paused")

    @router.post("/api/runs/{run_id}/resume", **steer)
    async def resume(run_id: str) -> dict[str, Any]:
        """Carry on from where it paused."""
        await service.get_run(run_id)
        return control(run_id, manager.resume, "running")

    @router.post(
        "/api/runs/{run_id}/pace",
        status_code=202,
        response_model=PaceSet,
        responses=answers(404, 409, 413, 422),
        openapi_extra=request_body(Pace),
    )
    async def pace(run_id: str, request: Request) -> dict[str, Any]:
        """Change a run's pace (simulated seconds per wall second) while it is queued,
        running or paused; 409 once it is final."""
        run = await service.get_run(run_id)
        try:
            wanted = Pace.model_validate_json(await read_body(request))
        except ValidationError as exc:
            raise ApiError(
                422,
                {
                    "errors": [
                        problem(None, ".".join(map(str, e["loc"])), e["msg"]) for e in exc.errors()
                    ]
                },
            ) from None
        if run["status"] in FINAL:
            raise ApiError(409, f"the run is already {run['status']}")
        try:
            manager.set_pace(run_id, wanted.pace)
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        return {"id": run_id, "pace": wanted.pace}

    @router.post(
        "/api/runs/{run_id}/goal",
        status_code=202,
        response_model=GoalSent,
        responses=answers(404, 409, 413, 422, 503),
        openapi_extra=request_body(Goal),
    )
    async def goal(run_id: str, request: Request, robot: RobotName = None) -> dict[str, Any]:
        """Drive a robot to a pose, then remote command resumes (its current task teleop
        only). ``?robot=`` names it (optional when the run has one robot); an unknown
        robot, or none named in a fleet run, answers 422, and so does a goal no path
        reaches (outside the map, in an obstacle, cut off)."""
        await service.get_run(run_id)
        try:
            target = Goal.model_validate_json(await read_body(request))
        except ValidationError as exc:
            raise ApiError(
                422,
                {
                    "errors": [
                        problem(None, ".".join(map(str, e["loc"])), e["msg"]) for e in exc.errors()
                    ]
                },
            ) from None
        x, y, yaw = target.x, target.y, target.yaw
        try:
            name, code, answer = await manager.goal(run_id, robot, x, y, yaw)
        except UnknownRobot as exc:
            raise ApiError(422, str(exc)) from None
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        except asyncio.TimeoutError:
            raise ApiError(503, "the run did not answer in time") from None
        if code != 202:
            raise ApiError(code, answer.get("detail", "refused"))
        return {"id": run_id, "goal": {"x": x, "y": y, "yaw": yaw}, "robot": name}

    @router.post(
        "/api/runs/{run_id}/rooms/{label}",
        response_model=RoomRecord,
        responses=answers(404, 409, 422, 500, 503),
    )
    async def record_room(run_id: str, label: str, robot: RobotName = None) -> JSONResponse:
        """Record a robot's current estimated pose under ``label`` in the run's recorder
        file (the seed's ``rosservice call room_service "kitchen"``). ``?robot=`` names
        the robot (optional when the run has one); an unknown one answers 422."""
        await service.get_run(run_id)
        label = label.strip()
        if not label or len(label) > MAX_LABEL or not label.isprintable():
            raise ApiError(422, f"a room label is 1 to {MAX_LABEL} printable characters")
        try:
            code, body = await manager.record_room(run_id, robot, label)
        except UnknownRobot as exc:
            raise ApiError(422, str(exc)) from None
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        except asyncio.TimeoutError:
            raise ApiError(503, "the run did not answer in time") from None
        return JSONResponse(body, status_code=code)

    return router
