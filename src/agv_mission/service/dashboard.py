"""The browser dashboard: the pages (runs, run, submit) and the routes only they need.

The service's app includes :data:`router` and mounts ``static/`` at ``/static``; the pages
are plain HTML + JavaScript (no build step, no CDN) so the dashboard works offline.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse

from agv_mission.service.models import Templates

STATIC_DIR = Path(__file__).resolve().parent / "static"

router = APIRouter()

# The demo missions offered as templates, in this order (others follow alphabetically).
_TEMPLATE_ORDER = (
    "patrol",
    "visit_rooms",
    "teleop",
    "patrol_subtree",
    "wander_tree",
    "kitchen_or_bedroom",
    "red_light_green_light",
)


def _page(name: str, status_code: int = 200) -> FileResponse:
    # no-cache: a dashboard upgraded in place must not run stale scripts against a new API
    return FileResponse(
        STATIC_DIR / name,
        status_code=status_code,
        media_type="text/html",
        headers={"Cache-Control": "no-cache"},
    )


def not_found_page() -> FileResponse:
    """The dashboard's 404 page: what a browser gets for an address that shows nothing."""
    return _page("notfound.html", 404)


@router.get("/", include_in_schema=False)
def runs_page() -> FileResponse:
    """Every run, live."""
    return _page("index.html")


@router.get("/runs/{run_id}", include_in_schema=False)
async def run_page(run_id: str, request: Request) -> FileResponse:
    """One run: live, then replayable from its directory (the page reads ``run_id`` itself);
    a 404 page for a run the service does not know."""
    if await request.app.state.registry.aget(run_id) is None:
        return not_found_page()
    return _page("run.html")


@router.get("/submit", include_in_schema=False)
def submit_page() -> FileResponse:
    """The mission editor."""
    return _page("submit.html")


def demo_templates() -> list[dict[str, str]]:
    """The demo missions shipped in the package (``data/missions``) plus the dashboard's own."""
    found: dict[str, str] = {}
    missions = resources.files("agv_mission") / "data" / "missions"
    if missions.is_dir():
        for item in missions.iterdir():
            if item.name.endswith(".yaml"):
                found[item.name.removesuffix(".yaml")] = item.read_text(encoding="utf-8")
    for path in (STATIC_DIR / "templates").glob("*.yaml"):
        found.setdefault(path.stem, path.read_text(encoding="utf-8"))

    def order(name: str) -> tuple[int, str]:
        rank = _TEMPLATE_ORDER.index(name) if name in _TEMPLATE_ORDER else len(_TEMPLATE_ORDER)
        return rank, name

    return [{"name": name, "yaml": found[name]} for name in sorted(found, key=order)]


@router.get("/api/templates", response_model=Templates, tags=["dashboard"])
def templates() -> dict[str, list[dict[str, str]]]:
    """The demo missions, for the submit page's template menu."""
    return {"templates": demo_templates()}
