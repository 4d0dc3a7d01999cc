"""The HTTP/WebSocket API of ``agv-mission serve`` (service-api.md), on FastAPI.

Safety: every ``/api`` request carries the bearer token when one is set (``?token=`` on
the live stream); request bodies are bounded (413); a mission may name built-in worlds
and robots and files under the data directory only; no CORS headers are ever sent and
requests from a browser page of another origin are refused, so a web page cannot drive
the service; YAML is read with ``safe_load`` only.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import importlib.util
import json
import math
import re
from collections.abc import Callable
from contextlib import asynccontextmanager
from importlib import metadata
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from fastapi import FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, JSONResponse
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from agv_mission.missions.errors import MissionError
from agv_mission.service.hub import KIND_BUDGET, Client
from agv_mission.service.registry import FINAL, STATUSES, Registry, Submission
from agv_mission.service.runs import NotActive, QueueFull, RunManager
from agv_mission.service.sandbox import DataDirGuard

try:
    __version__ = metadata.version("agv-mission")
except metadata.PackageNotFoundError:  # a source tree without an install
    __version__ = "0+unknown"

MAX_BODY = 1_000_000  # bytes of a request body
MAX_WS_MESSAGE = 4096  # bytes of a client message on the live stream
MAX_LABEL = 100
SEND_PERIOD = 0.05  # seconds between two sends to one live client (20 batches a second)


class ApiError(Exception):
    def __init__(self, status: int, detail: Any) -> None:
        self.status, self.detail = status, detail


class Settings:
    """What ``serve`` was started with."""

    def __init__(
        self,
        data_dir: Path,
        workers: int,
        queue_size: int = 1000,
        backend: str = "local",
        address: str | None = None,
        token: str | None = None,
    ) -> None:
        self.data_dir = data_dir
        self.workers = workers
        self.queue_size = queue_size
        self.backend = backend
        self.address = address
        self.token = token or None


def create_app(settings: Settings) -> FastAPI:
    registry = Registry(settings.data_dir)
    manager = RunManager(
        registry, settings.workers, settings.queue_size, settings.backend, settings.address
    )
    guard = DataDirGuard(settings.data_dir)

    @asynccontextmanager
    async def lifespan(app: FastAPI):  # type: ignore[no-untyped-def]
        await manager.start()
        yield
        await manager.shutdown()
        registry.close()

    app = FastAPI(
        title="agv-mission",
        version=__version__,
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
        openapi_url="/api/openapi.json",
    )
    app.state.manager = manager
    app.state.registry = registry

    def authorised(header: str | None, query: str | None) -> bool:
        if settings.token is None:
            return True
        given = query
        if header and header.lower().startswith("bearer "):
            given = header[7:].strip()
        return given is not None and hmac.compare_digest(given.encode(), settings.token.encode())

    class Guard:
        """Token and origin checks of every ``/api`` HTTP request (plain ASGI: no extra task
        or body queue per request, unlike ``BaseHTTPMiddleware``)."""

        def __init__(self, app: ASGIApp) -> None:
            self.app = app

        async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
            if scope["type"] == "http" and scope["path"].startswith("/api"):
                headers = Headers(scope=scope)
                refusal = None
                if not authorised(headers.get("authorization"), None):
                    refusal = JSONResponse(
                        {"detail": "missing or wrong bearer token"},
                        status_code=401,
                        headers={"WWW-Authenticate": "Bearer"},
                    )
                elif not same_origin(headers.get("origin"), headers.get("host")):
                    refusal = JSONResponse({"detail": "cross-origin requests are refused"}, 403)
                if refusal is not None:
                    await refusal(scope, receive, send)
                    return
            await self.app(scope, receive, send)

    app.add_middleware(Guard)

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        body = exc.detail if isinstance(exc.detail, dict) else {"detail": exc.detail}
        return JSONResponse(body, status_code=exc.status)

    # ------------------------------------------------------------------ helpers

    async def run_object(run: dict[str, Any]) -> dict[str, Any]:
        live = manager.live_progress(run["id"])
        if live is not None:
            run["progress"] = live
        if run["id"] in manager.active:
            run["status"] = manager.active[run["id"]].status
        if run["status"] in FINAL:
            run["result"] = await manager.results.get(run["id"])
        return run

    async def get_run(run_id: str) -> dict[str, Any]:
        """From the registry's cache (SQLite only on a miss, off the event loop)."""
        run = await registry.aget(run_id)
        if run is None:
            raise ApiError(404, f"no run {run_id!r}")
        return run

    async def submission(request: Request) -> Submission:
        body = await read_body(request)
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if ctype in ("application/yaml", "application/x-yaml", "text/yaml"):
            try:
                text = body.decode("utf-8")
            except UnicodeDecodeError:
                raise ApiError(422, {"errors": [_err(None, "", "the body is not UTF-8")]}) from None
            sets, seed = [], None
        elif ctype == "application/json":
            text, sets, seed = parse_json_submission(body)
        else:
            raise ApiError(415, "send application/json ({mission, set, seed}) or application/yaml")
        loaded = await asyncio.to_thread(validate, text, sets, seed)
        return Submission(loaded.name, text, sets, seed)

    def validate(text: str, sets: list[str], seed: int | None) -> Any:
        from agv_mission.missions.loader import load_mission

        try:
            return load_mission(
                settings.data_dir / "mission.yaml", sets, seed, text=text, path_guard=guard
            )
        except MissionError as exc:
            raise ApiError(
                422, {"errors": [_err(p.line, p.field, p.message) for p in exc.problems]}
            ) from None

    # ------------------------------------------------------------------ routes

    @app.get("/api/health")
    async def health() -> dict[str, Any]:
        return {
            "status": "ok",
            "version": __version__,
            "queued": len(manager.queue),
            "running": len(manager.active),
            "workers": settings.workers,
            "backend": settings.backend,
        }

    @app.post("/api/runs", status_code=201)
    async def submit(request: Request) -> JSONResponse:
        try:
            manager.check_room()
            sub = await submission(request)
            run = await manager.submit(sub)
        except QueueFull as exc:
            raise ApiError(429, str(exc)) from None
        return JSONResponse(run, status_code=201)

    @app.post("/api/validate")
    async def validate_route(request: Request) -> dict[str, Any]:
        body = await read_body(request)
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if ctype == "application/json":
            text, sets, seed = parse_json_submission(body)
        else:
            text, sets, seed = body.decode("utf-8", errors="replace"), [], None
        loaded = await asyncio.to_thread(validate, text, sets, seed)
        return {"ok": True, "mission": loaded.resolved()}

    @app.get("/api/runs")
    async def list_runs(status: str | None = None, limit: int = 100) -> dict[str, Any]:
        if status is not None and status not in STATUSES:
            raise ApiError(422, f"unknown status {status!r}; one of {sorted(STATUSES)}")
        if not 1 <= limit <= 1000:
            raise ApiError(422, "limit must be between 1 and 1000")
        runs = await registry.alist(status, limit)
        for run in runs:
            live = manager.live_progress(run["id"])
            if live is not None:
                run["progress"] = live
        return {"runs": runs}

    @app.get("/api/runs/{run_id}")
    async def one_run(run_id: str) -> dict[str, Any]:
        return await run_object(await get_run(run_id))

    def control(run_id: str, act: Callable[[str], None], status: str) -> dict[str, Any]:
        """Ask the run's worker to act; 409 when the run is not in a state to."""
        try:
            act(run_id)
        except NotActive as exc:
            raise ApiError(409, str(exc)) from None
        return {"id": run_id, "status": status}

    @app.post("/api/runs/{run_id}/cancel", status_code=202)
    async def cancel(run_id: str) -> dict[str, Any]:
        run = await get_run(run_id)
        if run["status"] in FINAL:
            raise ApiError(409, f"the run is already {run['status']}")
        return control(run_id, manager.cancel, "cancelling")

    @app.post("/api/runs/{run_id}/pause", status_code=202)
    async def pause(run_id: str) -> dict[str, Any]:
        await get_run(run_id)
        return control(run_id, manager.pause, "paused")

    @app.post("/api/runs/{run_id}/resume", status_code=202)
    async def resume(run_id: str) -> dict[str, Any]:
        await get_run(run_id)
        return control(run_id, manager.resume, "running")

    @app.post("/api/runs/{run_id}/goal", status_code=202)
    async def goal(run_id: str, request: Request) -> dict[str, Any]:
        await get_run(run_id)
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

    @app.post("/api/runs/{run_id}/rooms/{label}")
    async def record_room(run_id: str, label: str) -> JSONResponse:
        await get_run(run_id)
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

    @app.get("/api/runs/{run_id}/files")
    async def files(run_id: str) -> dict[str, Any]:
        await get_run(run_id)
        return {"files": await asyncio.to_thread(_file_names, registry.run_dir(run_id))}

    @app.get("/api/runs/{run_id}/files/{name}")
    async def one_file(run_id: str, name: str) -> FileResponse:
        await get_run(run_id)
        run_dir = registry.run_dir(run_id)
        path = run_dir / name
        if (
            "/" in name
            or "\\" in name
            or name.startswith(".")
            or not await asyncio.to_thread(_plain_file_in, path, run_dir)
        ):
            raise ApiError(404, f"no file {name!r} in run {run_id}")
        return FileResponse(path, media_type=_media_type(name))

    @app.websocket("/api/runs/{run_id}/live")
    async def live(websocket: WebSocket, run_id: str) -> None:
        if not authorised(
            websocket.headers.get("authorization"), websocket.query_params.get("token")
        ):
            await websocket.close(code=4401, reason="missing or wrong token")
            return
        if not same_origin(websocket.headers.get("origin"), websocket.headers.get("host")):
            await websocket.close(code=4403, reason="cross-origin")
            return
        run = await registry.aget(run_id)
        if run is None:
            await websocket.close(code=4404, reason="no such run")
            return
        await websocket.accept()
        hub = await manager.live.hub_for(run_id, run)
        client = hub.subscribe(_rate(websocket.query_params.get("rate")))
        sender = asyncio.create_task(_send_loop(websocket, client))
        try:
            while True:
                text = await websocket.receive_text()
                if len(text) > MAX_WS_MESSAGE:
                    continue
                _client_message(manager, run_id, client, text)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            hub.unsubscribe(client)
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender

    if importlib.util.find_spec("agv_mission.service.dashboard") is not None:
        from agv_mission.service import dashboard

        app.include_router(dashboard.router)
    static = Path(__file__).parent / "static"
    if static.is_dir():
        from fastapi.staticfiles import StaticFiles

        app.mount("/static", StaticFiles(directory=static), name="static")
    return app


async def _send_loop(websocket: WebSocket, client: Client) -> None:
    """Drain one client's queue, at most every :data:`SEND_PERIOD` seconds (a status
    change or the end at once): a message wakes no client by itself (that would be one
    task switch per client per worker step); what arrived meanwhile goes out together,
    thinned. The hub never waits for this."""
    loop = asyncio.get_running_loop()
    while True:
        await client.ready.wait()
        client.ready.clear()
        client.urgent.clear()
        started = loop.time()
        items, due = client.take(started)
        for kind, text in items:
            await websocket.send_text(text)
            if kind == "end":
                await websocket.close(code=1000)
                return
        if client.dropped:
            await websocket.close(code=1013, reason="too slow")
            return
        if due is not None:  # a held message falls due then
            loop.call_at(max(due, started + SEND_PERIOD), client.ready.set)
        rest = started + SEND_PERIOD - loop.time()
        if rest > 0 and not client.urgent.is_set():
            wake = loop.call_later(rest, client.urgent.set)
            await client.urgent.wait()
            wake.cancel()


def _rate(given: str | None) -> float:
    """``?rate=N``: at most N messages of each frequent kind (state, scan, particles,
    horizon) per wall second for this client (1 to the hub's budget; default: the budget)."""
    try:
        rate = float(given) if given is not None else KIND_BUDGET
    except ValueError:
        rate = KIND_BUDGET
    return min(max(rate, 1.0), KIND_BUDGET) if math.isfinite(rate) else KIND_BUDGET


def _client_message(manager: RunManager, run_id: str, client: Client, text: str) -> None:
    try:
        message = json.loads(text)
    except ValueError:
        return
    if not isinstance(message, dict):
        return
    kind = message.get("type")
    if kind == "ping":
        client.put("pong", '{"type":"pong"}')
    elif kind == "cmd_vel":
        try:
            v, w = float(message.get("v", 0.0)), float(message.get("w", 0.0))
        except (TypeError, ValueError):
            return
        if math.isfinite(v) and math.isfinite(w):
            manager.cmd_vel(run_id, v, w)


async def read_body(request: Request) -> bytes:
    """The request body, refusing (413) anything larger than :data:`MAX_BODY`."""
    declared = request.headers.get("content-length")
    if declared is not None:
        with contextlib.suppress(ValueError):
            if int(declared) > MAX_BODY:
                raise ApiError(413, f"the body is larger than {MAX_BODY} bytes")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > MAX_BODY:
            raise ApiError(413, f"the body is larger than {MAX_BODY} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


def parse_json_submission(body: bytes) -> tuple[str, list[str], int | None]:
    try:
        doc = json.loads(body)
    except ValueError as exc:
        raise ApiError(422, {"errors": [_err(None, "", f"invalid JSON body: {exc}")]}) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("mission"), str):
        raise ApiError(
            422, {"errors": [_err(None, "mission", "the body needs 'mission': the YAML text")]}
        )
    unknown = set(doc) - {"mission", "set", "seed"}
    if unknown:
        raise ApiError(
            422, {"errors": [_err(None, sorted(unknown)[0], "unknown key (mission, set, seed)")]}
        )
    sets = doc.get("set") or []
    if not isinstance(sets, list) or not all(isinstance(s, str) for s in sets):
        raise ApiError(422, {"errors": [_err(None, "set", "a list of KEY=VALUE strings")]})
    seed = doc.get("seed")
    if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool) or seed < 0):
        raise ApiError(422, {"errors": [_err(None, "seed", "a non-negative integer")]})
    return doc["mission"], sets, seed


def _err(line: int | None, field: str, message: str) -> dict[str, Any]:
    """One problem as the contract spells it: list indices in brackets
    (``tasks[0].waypoints[1].yaw``, where the command line prints ``tasks.0.waypoints.1.yaw``)."""
    return {"line": line, "field": _INDEX.sub(r"[\1]", field), "message": message}


_INDEX = re.compile(r"\.(\d+)(?=\.|$)")


def same_origin(origin: str | None, host: str | None) -> bool:
    """A browser sends ``Origin``; only pages the service served itself may call it."""
    if not origin:
        return True
    return urlsplit(origin).netloc == (host or "")


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


def _media_type(name: str) -> str | None:
    suffix = Path(name).suffix.lower()
    return {
        ".json": "application/json",
        ".jsonl": "application/x-ndjson",
        ".yaml": "application/yaml",
        ".csv": "text/csv",
        ".png": "image/png",
        ".txt": "text/plain",
        ".pgm": "image/x-portable-graymap",
        ".log": "text/plain",
    }.get(suffix)
