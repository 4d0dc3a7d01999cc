"""``agv-mission submit``: a mission to a running service, optionally followed live."""

from __future__ import annotations

import asyncio
import json
import os
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlsplit, urlunsplit

import httpx

from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.service.sandbox import NamedFiles


class ClientError(Exception):
    """The service could not be reached or refused the request (not the mission)."""


def _headers(token: str | None) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"} if token else {}


def submit(
    mission: Path,
    sets: list[str],
    seed: int | None,
    server: str,
    token: str | None,
    pace: float | None = None,
) -> dict[str, Any]:
    """POST the mission, with the files it names (multipart) when it names any, at
    ``pace`` simulated seconds per wall second (None: as fast as it goes); the run
    object. Raises MissionError on invalid input (naming the file), ClientError when the
    service cannot be reached or refuses."""
    try:
        text = mission.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MissionError([Problem(str(mission), None, "", f"cannot read: {exc}")]) from None
    files = mission_files(mission, text, sets, seed)
    url, headers = server.rstrip("/") + "/api/runs", _headers(token)
    try:
        if files:
            response = _post_with_files(url, headers, mission, text, sets, seed, files, pace)
        else:
            body: dict[str, Any] = {"mission": text, "set": sets}
            if seed is not None:
                body["seed"] = seed
            if pace is not None:
                body["pace"] = pace
            response = httpx.post(url, json=body, headers=headers, timeout=60.0)
    except httpx.HTTPError as exc:
        raise ClientError(f"cannot reach {server}: {exc}") from None
    if response.status_code == 422:
        errors = response.json().get("errors", [])
        raise MissionError(
            [Problem(str(mission), e.get("line"), e.get("field", ""), e["message"]) for e in errors]
        )
    if response.status_code in (413, 415):  # what was sent cannot be taken: the input's fault
        raise MissionError([Problem(str(mission), None, "", _detail(response))])
    if response.status_code != 201:
        raise ClientError(f"{server} answered {response.status_code}: {_detail(response)}")
    return response.json()


_COLLECTED = "\0collected"  # the guard's answer that stops the loader once it named its files


def mission_files(mission: Path, text: str, sets: list[str], seed: int | None) -> list[Path]:
    """The files of this machine the mission names (world map YAML and its image, rooms,
    robot and recorder files), which travel with it. Invalid input raises MissionError
    here, as ``run`` would report it; a mission on built-in worlds and robots only is
    validated whole."""
    from agv_mission.missions.load.loader import load_mission

    named = NamedFiles()

    def collect(field: str, path: Path) -> str:
        named(field, path)
        return _COLLECTED

    try:
        load_mission(mission, sets, seed, text=text, path_guard=collect)
    except MissionError as exc:
        problems = [p for p in exc.problems if p.message != _COLLECTED]
        if problems:
            raise MissionError(problems) from None
    found: list[Path] = []
    for path in named.paths:
        if path.is_file() and path.resolve() not in {p.resolve() for p in found}:
            found.append(path)
    return found


def _post_with_files(
    url: str,
    headers: dict[str, str],
    mission: Path,
    text: str,
    sets: list[str],
    seed: int | None,
    files: list[Path],
    pace: float | None = None,
) -> httpx.Response:
    """Multipart: the mission and its files, named by their paths relative to the folder
    that holds them all (so ``../maps/house.yaml`` keeps its place beside the mission)."""
    where = [mission.resolve(), *(f.resolve() for f in files)]
    root = Path(os.path.commonpath([p.parent for p in where]))
    data: dict[str, Any] = {
        "mission": text,
        "mission_path": where[0].relative_to(root).as_posix(),
        "set": sets,
    }
    if seed is not None:
        data["seed"] = str(seed)
    if pace is not None:
        data["pace"] = repr(pace)
    with ExitStack() as stack:
        parts = [
            ("files", (p.relative_to(root).as_posix(), stack.enter_context(p.open("rb"))))
            for p in where[1:]
        ]
        return httpx.post(url, data=data, files=parts, headers=headers, timeout=120.0)


def _detail(response: httpx.Response) -> str:
    try:
        return str(response.json().get("detail", response.text))
    except ValueError:
        return response.text[:200]


def live_url(server: str, run_id: str, token: str | None) -> str:
    parts = urlsplit(server.rstrip("/"))
    scheme = "wss" if parts.scheme == "https" else "ws"
    query = f"token={quote(token)}" if token else ""
    return urlunsplit((scheme, parts.netloc, f"{parts.path}/api/runs/{run_id}/live", query, ""))


def follow(
    server: str,
    run_id: str,
    token: str | None,
    on_message: Callable[[dict[str, Any]], None],
) -> dict[str, Any]:
    """Stream the run until it ends; returns the final run object."""
    asyncio.run(_follow(live_url(server, run_id, token), on_message))
    return get_run(server, run_id, token)


async def _follow(url: str, on_message: Callable[[dict[str, Any]], None]) -> None:
    import websockets

    try:
        async with websockets.connect(url, max_size=1 << 24) as ws:
            async for text in ws:
                message = json.loads(text)
                on_message(message)
                if message.get("type") == "end":
                    return
    except (OSError, websockets.exceptions.WebSocketException) as exc:
        raise ClientError(f"live stream of {url.split('?')[0]} failed: {exc}") from None


def get_run(server: str, run_id: str, token: str | None) -> dict[str, Any]:
    try:
        response = httpx.get(
            f"{server.rstrip('/')}/api/runs/{run_id}", headers=_headers(token), timeout=30.0
        )
    except httpx.HTTPError as exc:
        raise ClientError(f"cannot reach {server}: {exc}") from None
    if response.status_code != 200:
        raise ClientError(f"{server} answered {response.status_code}: {_detail(response)}")
    return response.json()
