"""Request bodies of the API and its error answers: bounded reads (413), mission
submissions (JSON or YAML), and problems spelt as the contract spells them (422)."""

from __future__ import annotations

import contextlib
import json
from collections.abc import AsyncIterator
from pathlib import Path, PurePosixPath
from typing import Any

from fastapi import Request

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.schema.mission import MAX_SEED
from agv_mission.service.context import ApiError, Service

MAX_BODY = 1_000_000  # bytes of a request body
YAML_TYPES = ("application/yaml", "application/x-yaml", "text/yaml")


async def read_body(request: Request) -> bytes:
    """The request body, refusing (413) anything larger than :data:`MAX_BODY`."""
    return b"".join([chunk async for chunk in bounded_stream(request, MAX_BODY)])


async def bounded_stream(request: Request, limit: int) -> AsyncIterator[bytes]:
    """The request body as it arrives, refusing (413) more than ``limit`` bytes."""
    declared = request.headers.get("content-length")
    if declared is not None:
        with contextlib.suppress(ValueError):
            if int(declared) > limit:
                raise ApiError(413, f"the body is larger than {limit} bytes")
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise ApiError(413, f"the body is larger than {limit} bytes")
        yield chunk


def content_type(request: Request) -> str:
    """The media type alone (no parameters), lower case."""
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def mission_input(request: Request) -> tuple[str, list[str], int | None, float | None]:
    """The mission text, ``--set`` overrides, seed and pace of a request: JSON
    ``{mission, set, seed, pace}`` or YAML text (422 for a malformed body, 415 for another
    media type). Submitting and validating read bodies the same way."""
    body = await read_body(request)
    ctype = content_type(request)
    if ctype in YAML_TYPES:
        try:
            return body.decode("utf-8"), [], None, None
        except UnicodeDecodeError:
            raise ApiError(422, {"errors": [problem(None, "", "the body is not UTF-8")]}) from None
    if ctype == "application/json":
        return parse_json_submission(body)
    raise ApiError(415, "send application/json ({mission, set, seed}) or application/yaml")


def validate(
    service: Service,
    text: str,
    sets: list[str],
    seed: int | None,
    source: Path | None = None,
    guard: Any = None,
) -> Any:
    """The loaded mission, read as the command line reads it (from ``source``, default a
    mission file in the data directory) but confined to the data directory; its problems
    as a 422. A mission's ``output.dir`` other than ``runs`` is refused: a service run's
    directory is ``DATA/runs/<id>`` (``output.bag`` is honoured)."""
    from agv_mission.missions.load.loader import load_mission

    try:
        loaded = load_mission(
            source or service.settings.data_dir / "mission.yaml",
            sets,
            seed,
            text=text,
            path_guard=guard or service.guard,
        )
    except MissionError as exc:
        raise ApiError(
            422, {"errors": [problem(p.line, p.field, p.message) for p in exc.problems]}
        ) from None
    output = loaded.mission.output
    if PurePosixPath(output.dir) != PurePosixPath("runs"):
        raise ApiError(
            422,
            {
                "errors": [
                    problem(
                        _line_of(text, ("output",)),
                        "output",
                        f"the service cannot write runs to {output.dir!r}: a service run's "
                        "directory is DATA/runs/<run id> (GET /api/runs/{id}/files); "
                        "remove output (or make it runs); output.bag is honoured",
                    )
                ]
            },
        )
    return loaded


def _line_of(text: str, path: tuple[str, ...]) -> int | None:
    """The line of a key in the mission text (None when an override set it)."""
    from agv_mission.missions.load.yaml_lines import load_with_lines

    with contextlib.suppress(Exception):
        return load_with_lines(text)[1].get(path)
    return None


def parse_json_submission(body: bytes) -> tuple[str, list[str], int | None, float | None]:
    try:
        doc = json.loads(body)
    except ValueError as exc:
        raise ApiError(422, {"errors": [problem(None, "", f"invalid JSON body: {exc}")]}) from None
    except RecursionError:
        message = "invalid JSON body: nested deeper than the parser follows"
        raise ApiError(422, {"errors": [problem(None, "", message)]}) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("mission"), str):
        raise ApiError(
            422, {"errors": [problem(None, "mission", "the body needs 'mission': the YAML text")]}
        )
    unknown = set(doc) - {"mission", "set", "seed", "pace"}
    if unknown:
        message = "unknown key (mission, set, seed, pace)"
        raise ApiError(422, {"errors": [problem(None, sorted(unknown)[0], message)]})
    sets = doc.get("set") or []
    if not isinstance(sets, list) or not all(isinstance(s, str) for s in sets):
        raise ApiError(422, {"errors": [problem(None, "set", "a list of KEY=VALUE strings")]})
    seed = doc.get("seed")
    if seed is not None and (
        not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed <= MAX_SEED
    ):
        message = f"an integer in 0..{MAX_SEED} (63 bits)"
        raise ApiError(422, {"errors": [problem(None, "seed", message)]})
    return doc["mission"], sets, seed, pace_of(doc.get("pace"))


def pace_of(given: object) -> float | None:
    """A submission's pace (None: as fast as it goes); 422 unless a positive number."""
    from agv_mission.missions.run.pacing import check_pace

    try:
        return check_pace(given)  # type: ignore[arg-type]
    except ValueError as exc:
        raise ApiError(422, {"errors": [problem(None, "pace", str(exc))]}) from None


def problem(line: int | None, field: str, message: str) -> dict[str, Any]:
    """One problem as the contract spells it: the field's path as the command line spells
    it, everywhere (``tasks.0.waypoints.1.yaw``)."""
    return {"line": line, "field": field, "message": message}
