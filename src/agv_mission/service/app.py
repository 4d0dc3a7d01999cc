"""The HTTP/WebSocket API of ``agv-mission serve`` (service-api.md), on FastAPI.

Safety: every ``/api`` request carries the bearer token when one is set (``?token=`` on
the live stream, :mod:`~agv_mission.service.access`); request bodies are bounded (413,
:mod:`~agv_mission.service.bodies`); a mission may name built-in worlds and robots and
files under the data directory only; no CORS headers are ever sent and requests from a
browser page of another origin are refused, so a web page cannot drive the service; YAML
is read with ``safe_load`` only.

The routes are grouped by resource: runs (:mod:`~agv_mission.service.runs_api`), their
files (:mod:`~agv_mission.service.files_api`), the live stream
(:mod:`~agv_mission.service.live_api`) and the dashboard's pages.
"""

from __future__ import annotations

import importlib.util
from contextlib import asynccontextmanager
from importlib import metadata
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from agv_mission.service.access import AccessGuard
from agv_mission.service.context import ApiError, Service, Settings
from agv_mission.service.files_api import files_router
from agv_mission.service.live_api import live_router
from agv_mission.service.registry import Registry
from agv_mission.service.runs import RunManager
from agv_mission.service.runs_api import runs_router
from agv_mission.service.sandbox import DataDirGuard

__all__ = ["Settings", "create_app"]

try:
    __version__ = metadata.version("agv-mission")
except metadata.PackageNotFoundError:  # a source tree without an install
    __version__ = "0+unknown"


def create_app(settings: Settings) -> FastAPI:
    registry = Registry(settings.data_dir)
    manager = RunManager(
        registry, settings.workers, settings.queue_size, settings.backend, settings.address
    )
    service = Service(settings, registry, manager, DataDirGuard(settings.data_dir))

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
    app.add_middleware(AccessGuard, token=settings.token)

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        body = exc.detail if isinstance(exc.detail, dict) else {"detail": exc.detail}
        return JSONResponse(body, status_code=exc.status)

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

    app.include_router(runs_router(service))
    app.include_router(files_router(service))
    app.include_router(live_router(service))
    if importlib.util.find_spec("agv_mission.service.dashboard") is not None:
        from agv_mission.service import dashboard

        app.include_router(dashboard.router)
    static = Path(__file__).parent / "static"
    if static.is_dir():
        from fastapi.staticfiles import StaticFiles

        app.mount("/static", StaticFiles(directory=static), name="static")
    return app
