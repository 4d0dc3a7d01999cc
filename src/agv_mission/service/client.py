"""``agv-mission submit``: a mission to a running service, optionally followed live."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlsplit, urlunsplit

import httpx

from agv_mission.missions.errors import MissionError, Problem


class ClientError(Exception):
    """The service could not be reached or refused the request (not the mission)."""


def _headers(token: str | None) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"} if token else {}


def submit(
    mission: Path, sets: list[str], seed: int | None, server: str, token: str | None
) -> dict[str, Any]:
    """POST the mission; the run object. Raises MissionError on 422 (naming the file)."""
    try:
        text = mission.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise MissionError([Problem(str(mission), None, "", f"cannot read: {exc}")]) from None
    body: dict[str, Any] = {"mission": text, "set": sets}
    if seed is not None:
        body["seed"] = seed
    try:
        response = httpx.post(
            server.rstrip("/") + "/api/runs", json=body, headers=_headers(token), timeout=60.0
        )
    except httpx.HTTPError as exc:
        raise ClientError(f"cannot reach {server}: {exc}") from None
    if response.status_code == 422:
        errors = response.json().get("errors", [])
        raise MissionError(
            [Problem(str(mission), e.get("line"), e.get("field", ""), e["message"]) for e in errors]
        )
    if response.status_code != 201:
        raise ClientError(f"{server} answered {response.status_code}: {_detail(response)}")
    return response.json()


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
