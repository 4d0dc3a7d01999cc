"""What ``POST /api/runs`` submits (:func:`submission`): a mission as JSON or YAML, or one
that travels with its files as ``multipart/form-data``.

Parts: ``mission`` (the YAML text, as a text field or a file part), ``mission_path``
(where the mission file sits among the files; default the mission part's filename, else
``mission.yaml``), ``set`` (repeated), ``seed``, ``pace``, and ``files`` (repeated): each file's
filename is its path relative to the mission file's folder, as the mission names it
(``maps/house.yaml``).

They land in the run's own directory, ``DATA/runs/<id>/inputs/``, confined: a name is a
relative path without ``..``, hidden or empty parts; at most :data:`MAX_FILES` files of
:data:`MAX_UPLOAD` bytes together; and only files the mission names (its world's map YAML
and image, rooms file, robot file, recorder file) are taken. The mission is then read
from there under the same data-directory guard as any other submission.
"""

from __future__ import annotations

import asyncio
import shutil
from pathlib import Path, PurePosixPath

from fastapi import Request
from starlette.datastructures import FormData, UploadFile
from starlette.formparsers import MultiPartException, MultiPartParser

from agv_mission.service.bodies import (
    bounded_stream,
    content_type,
    mission_input,
    pace_of,
    problem,
    validate,
)
from agv_mission.service.context import ApiError, Service
from agv_mission.service.registry import Submission
from agv_mission.service.sandbox import NamedFiles

MAX_UPLOAD = 64_000_000  # bytes of one multipart submission (a large map image fits)
MAX_FILES = 32
MAX_NAME = 255  # characters of a file's relative path
MAX_DEPTH = 8  # folders in a file's relative path
INPUTS = "inputs"


def invalid(field: str, message: str) -> ApiError:
    return ApiError(422, {"errors": [problem(None, field, message)]})


def safe_name(name: str | None, field: str) -> PurePosixPath:
    """A file's relative path, refused (422) unless it stays inside the run directory."""
    if not name:
        raise invalid(field, "a file part needs a filename (its path relative to the mission)")
    path = PurePosixPath(name)
    if (
        len(name) > MAX_NAME
        or "\\" in name
        or not name.isprintable()
        or path.is_absolute()
        or len(path.parts) > MAX_DEPTH + 1
        or any(part in ("", ".", "..") or part.startswith(".") for part in path.parts)
    ):
        raise invalid(
            field,
            f"{name!r}: a file's name is its path relative to the mission, without '..', "
            f"hidden or absolute parts, at most {MAX_NAME} characters",
        )
    return path


async def read_form(request: Request) -> FormData:
    try:
        parser = MultiPartParser(
            request.headers,
            bounded_stream(request, MAX_UPLOAD),
            max_files=MAX_FILES + 1,  # the mission may be a file part too
            max_fields=100,
            max_part_size=1_000_000,
        )
        return await parser.parse()
    except MultiPartException as exc:
        if "maximum size" in exc.message:  # a text field larger than a mission may be
            raise ApiError(413, f"multipart body: {exc.message}") from None
        raise invalid("", f"malformed multipart body: {exc.message}") from None


async def upload(service: Service, request: Request) -> tuple[Submission, str]:
    """Store the files in a new run's directory and validate the mission among them;
    the submission and its run id. Nothing stays behind when it is refused."""
    form = await read_form(request)
    try:
        mission = form.get("mission")
        if isinstance(mission, UploadFile):
            default_path = mission.filename or "mission.yaml"
            raw = await mission.read()
        elif isinstance(mission, str):
            default_path, raw = "mission.yaml", mission.encode("utf-8")
        else:
            raise invalid("mission", "the body needs a 'mission' part: the YAML text")
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise invalid("mission", "the mission is not UTF-8") from None
        given_path = form.get("mission_path")
        mission_path = safe_name(
            given_path if isinstance(given_path, str) and given_path else default_path,
            "mission_path",
        )
        sets = [s for s in form.getlist("set") if isinstance(s, str)]
        if len(sets) != len(form.getlist("set")):
            raise invalid("set", "each set part is a KEY=VALUE text field")
        seed = _seed(form.get("seed"))
        pace = _pace(form.get("pace"))
        files = form.getlist("files")
        if len(files) > MAX_FILES:
            raise invalid("files", f"at most {MAX_FILES} files travel with a mission")
        uploads: dict[PurePosixPath, UploadFile] = {}
        for item in files:
            if not isinstance(item, UploadFile):
                raise invalid("files", "each files part is a file (with its filename)")
            name = safe_name(item.filename, "files")
            if name in uploads:
                raise invalid("files", f"{name}: sent twice")
            if name == mission_path:
                raise invalid("files", f"{name}: that is the mission itself")
            uploads[name] = item
        run_id = service.registry.new_id()
        inputs = service.registry.run_dir(run_id) / INPUTS
        try:
            await _store(inputs, mission_path, text, uploads)
            guard = NamedFiles(service.guard)
            loaded = await asyncio.to_thread(
                validate, service, text, sets, seed, inputs / mission_path, guard
            )
            named = {p.resolve() for p in guard.paths}
            for name in uploads:
                if (inputs / name).resolve() not in named:
                    raise invalid(
                        "files",
                        f"{name}: the mission names no such file (files travel with a "
                        "mission only as its world, map image, rooms, robot or recorder)",
                    )
        except BaseException:
            await asyncio.to_thread(shutil.rmtree, inputs.parent, True)
            raise
    finally:
        await form.close()
    return Submission(loaded.name, text, sets, seed, f"{INPUTS}/{mission_path}", pace), run_id


def _pace(given: object) -> float | None:
    """A multipart ``pace`` text field (absent or empty: as fast as it goes)."""
    if given is None or given == "":
        return None
    try:
        value = float(str(given))
    except ValueError:
        raise invalid("pace", "simulated seconds per wall second: a number") from None
    return pace_of(value)


def _seed(given: object) -> int | None:
    if given is None or given == "":
        return None
    try:
        seed = int(str(given))
    except ValueError:
        raise invalid("seed", "a non-negative integer") from None
    if seed < 0:
        raise invalid("seed", "a non-negative integer")
    return seed


async def _store(
    inputs: Path, mission_path: PurePosixPath, text: str, uploads: dict[PurePosixPath, UploadFile]
) -> None:
    """Write the mission and the files under ``inputs`` (a fresh folder)."""
    await asyncio.to_thread(inputs.mkdir, parents=True)
    target = inputs / mission_path
    await asyncio.to_thread(target.parent.mkdir, parents=True, exist_ok=True)
    await asyncio.to_thread(target.write_text, text, "utf-8")
    for name, item in uploads.items():
        target = inputs / name
        await asyncio.to_thread(target.parent.mkdir, parents=True, exist_ok=True)
        await item.seek(0)
        with target.open("wb") as out:
            while chunk := await item.read(1 << 20):
                await asyncio.to_thread(out.write, chunk)


async def submission(service: Service, request: Request) -> tuple[Submission, str | None]:
    """A run to queue, validated off the event loop (422 with the problems), and the id
    its files were stored under when it came with files (multipart)."""
    if content_type(request) == "multipart/form-data":
        return await upload(service, request)
    text, sets, seed, pace = await mission_input(request)
    loaded = await asyncio.to_thread(validate, service, text, sets, seed)
    return Submission(loaded.name, text, sets, seed, pace=pace), None
