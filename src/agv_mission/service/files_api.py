"""A run directory's files over the API: the list, and one file (never a path out of it)."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from fastapi import APIRouter
from fastapi.responses import FileResponse

from agv_mission.service.context import ApiError, Service
from agv_mission.service.models import FileList, answers

MEDIA_TYPES = {
    ".json": "application/json",
    ".jsonl": "application/x-ndjson",
    ".yaml": "application/yaml",
    ".csv": "text/csv",
    ".png": "image/png",
    ".txt": "text/plain",
    ".pgm": "image/x-portable-graymap",
    ".log": "text/plain",
}


def files_router(service: Service) -> APIRouter:
    """``/api/runs/{run_id}/files`` for one service."""
    router = APIRouter(tags=["files"])
    registry = service.registry

    @router.get("/api/runs/{run_id}/files", response_model=FileList, responses=answers(404))
    async def files(run_id: str) -> dict[str, Any]:
        """The run directory's files."""
        await service.get_run(run_id)
        return {"files": await asyncio.to_thread(_file_names, registry.run_dir(run_id))}

    one = answers(404)
    one[200] = {
        "description": "the file, as its name's media type (application/octet-stream else)",
        "content": {
            media: {"schema": {"type": "string", "format": "binary"}}
            for media in sorted({*MEDIA_TYPES.values(), "application/octet-stream"})
        },
    }

    @router.get("/api/runs/{run_id}/files/{name}", response_class=FileResponse, responses=one)
    async def one_file(run_id: str, name: str) -> FileResponse:
        """One file of the run directory (``result.json``, ``trajectory.csv``,
        ``run.png``, ``mission.yaml``, saved maps, logs)."""
        await service.get_run(run_id)
        run_dir = registry.run_dir(run_id)
        path = run_dir / name
        if (
            "/" in name
            or "\\" in name
            or name.startswith(".")
            or not await asyncio.to_thread(_plain_file_in, path, run_dir)
        ):
            raise ApiError(404, f"no file {name!r} in run {run_id}")
        return FileResponse(path, media_type=MEDIA_TYPES.get(Path(name).suffix.lower()))

    return router


def _file_names(run_dir: Path) -> list[str]:
    if not run_dir.is_dir():
        return []
    return sorted(
        p.name
        for p in run_dir.iterdir()
        if p.is_file() and not p.is_symlink() and not p.name.startswith(".")
    )


def _plain_file_in(path: Path, run_dir: Path) -> bool:
    """A regular file directly in ``run_dir`` (no symlink out of it)."""
    return path.is_file() and not path.is_symlink() and path.resolve().parent == run_dir.resolve()
