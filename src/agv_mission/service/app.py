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

import fastapi_offline
from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, JSONResponse, Response
from starlette.exceptions import HTTPException as StarletteHTTPException

from agv_mission.service.access import AccessGuard
from agv_mission.service.bodies import problem
from agv_mission.service.context import ApiError, Service, Settings
from agv_mission.service.files_api import files_router
from agv_mission.service.live_api import LIVE_DOC, live_router
from agv_mission.service.models import Health, body_schemas
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
        registry,
        settings.workers,
        settings.queue_size,
        settings.backend,
        settings.address,
        observers=settings.observers,
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
        summary="Missions for differential-drive indoor robots, run in simulation.",
        description=DESCRIPTION + LIVE_DOC,
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
        openapi_url="/openapi.json",
        generate_unique_id_function=lambda route: route.name,  # operationId: submit, one_run
    )
    app.state.manager = manager
    app.state.registry = registry
    app.add_middleware(AccessGuard, token=settings.token)

    @app.exception_handler(ApiError)
    async def _api_error(request: Request, exc: ApiError) -> JSONResponse:
        if isinstance(exc.detail, dict):
            body = dict(exc.detail)
            if body.get("errors") and "detail" not in body:
                body["detail"] = body["errors"][0]["message"]
        elif exc.status == 422:  # every 422 lists problems, as a mission's do
            body = {"errors": [problem(None, "", str(exc.detail))], "detail": str(exc.detail)}
        else:
            body = {"detail": exc.detail}
        return JSONResponse(body, status_code=exc.status)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> Response:
        """An unknown page answers a browser with the dashboard's 404 page; API clients
        (and everything under /api) get the JSON answer."""
        wants_page = "text/html" in request.headers.get("accept", "")
        if exc.status_code == 404 and wants_page and not request.url.path.startswith("/api"):
            from agv_mission.service.dashboard import not_found_page

            return not_found_page()
        return await http_exception_handler(request, exc)

    @app.exception_handler(RequestValidationError)
    async def _bad_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            problem(None, ".".join(str(p) for p in e["loc"][1:]), e["msg"]) for e in exc.errors()
        ]
        return JSONResponse({"errors": errors, "detail": errors[0]["message"]}, status_code=422)

    def openapi() -> dict[str, Any]:
        """FastAPI's document plus the bodies the routes read themselves."""
        if app.openapi_schema is None:
            doc = get_openapi(
                title=app.title,
                version=app.version,
                summary=app.summary,
                description=app.description,
                routes=app.routes,
            )
            components = doc.setdefault("components", {})
            components.setdefault("schemas", {}).update(body_schemas())
            # `serve --token`: every /api request carries it (Swagger UI's "Authorize")
            components["securitySchemes"] = {
                "bearer": {"type": "http", "scheme": "bearer", "description": "serve --token"}
            }
            doc["security"] = [{"bearer": []}, {}]  # {}: a service started without a token
            app.openapi_schema = doc
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]

    @app.get("/api/openapi.json", include_in_schema=False)
    async def openapi_alias() -> JSONResponse:
        """The OpenAPI document where earlier versions served it."""
        return JSONResponse(app.openapi())

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        """Swagger UI from the package's own assets: the docs work with no network."""
        return get_swagger_ui_html(
            openapi_url="/openapi.json",
            title="agv-mission API",
            swagger_js_url="/docs-assets/swagger-ui-bundle.js",
            swagger_css_url="/docs-assets/swagger-ui.css",
            swagger_favicon_url="/docs-assets/favicon.png",
        )

    @app.get("/api/health", response_model=Health, tags=["service"])
    async def health() -> dict[str, Any]:
        """Liveness and load."""
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
    from fastapi.staticfiles import StaticFiles

    app.mount("/docs-assets", StaticFiles(directory=DOCS_ASSETS), name="docs-assets")
    return app


DOCS_ASSETS = Path(fastapi_offline.__file__).parent / "static"  # Swagger UI 5, ReDoc (MIT)

DESCRIPTION = """Runs missions (the YAML mission format of `agv-mission run`) in simulation, for many
clients. Submit a mission with `POST /api/runs`, follow it with `GET /api/runs/{id}` or
the live stream, fetch its files with `GET /api/runs/{id}/files/{name}`.

With a token (`serve --token`), every `/api` request carries
`Authorization: Bearer TOKEN`.
"""
