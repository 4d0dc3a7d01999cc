"""A run directory's files over the API: the list, and one file (never a path out of it).

Every file is listed, the bag's too (``bag/metadata.yaml``, ``bag/bag_0.mcap``), by its
path relative to the run directory; a folder (``bag``) is also served whole, as a zip.
"""

from __future__ import annotations

import asyncio
import io
import zipfile
from pathlib import Path
from typing import Any

from fastapi import APIRouter
from fastapi.responses import FileResponse, Response

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
    ".mcap": "application/octet-stream",
    ".btlog": "application/octet-stream",
    ".zip": "application/zip",
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

    @router.get("/api/runs/{run_id}/files/{name:path}", response_class=FileResponse, responses=one)
    async def one_file(run_id: str, name: str) -> Response:
        """One file of the run directory by its listed path (``result.json``,
        ``trajectory.csv``, ``run.png``, ``mission.yaml``, ``bag/metadata.yaml``, saved
        maps, logs); a folder (``bag``) as a zip of its files."""
        await service.get_run(run_id)
        run_dir = registry.run_dir(run_id)
        path = await asyncio.to_thread(_inside, run_dir, name)
        if path is None:
            raise ApiError(404, f"no file {name!r} in run {run_id}")
        if path.is_dir():
            data = await asyncio.to_thread(_zipped, path)
            headers = {"Content-Disposition": f'attachment; filename="{path.name}.zip"'}
            return Response(data, media_type="application/zip", headers=headers)
        return FileResponse(path, media_type=MEDIA_TYPES.get(Path(name).suffix.lower()))

    return router


def _file_names(run_dir: Path) -> list[str]:
    """Every regular file under ``run_dir`` (no symlinks, nothing hidden), as a relative
    POSIX path."""
    if not run_dir.is_dir():
        return []
    out = []
    for p in run_dir.rglob("*"):
        rel = p.relative_to(run_dir)
        if any(part.startswith(".") for part in rel.parts):
            continue
        if _inside(run_dir, rel.as_posix()) is not None and p.is_file():
            out.append(rel.as_posix())
    return sorted(out)


def _inside(run_dir: Path, name: str) -> Path | None:
    """The file or folder ``name`` (a listed relative path) under ``run_dir``, or None:
    no absolute paths, no ``..`` or hidden parts, no backslashes, no symlinks."""
    parts = name.split("/")
    if not name or "\\" in name or any(not p or p.startswith(".") for p in parts):
        return None
    path = run_dir.joinpath(*parts)
    steps = [run_dir.joinpath(*parts[: i + 1]) for i in range(len(parts))]
    if any(s.is_symlink() for s in steps) or not (path.is_file() or path.is_dir()):
        return None
    if not path.resolve().is_relative_to(run_dir.resolve()) or path == run_dir:
        return None
    return path


def _zipped(folder: Path) -> bytes:
    """``folder``'s files as a zip (stored: a bag's MCAP is compressed already)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as zf:
        for p in sorted(folder.rglob("*")):
            rel = p.relative_to(folder)
            if p.is_file() and not p.is_symlink() and not any(x.startswith(".") for x in rel.parts):
                zf.write(p, f"{folder.name}/{rel.as_posix()}")
    return buf.getvalue()
