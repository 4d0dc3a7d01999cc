"""The dashboard's routes against a real `agv-mission serve` on a loopback port (no browser).

The browser tests are in ``test_dashboard_browser.py``; this file checks what they stand on:
the pages and static files are served from the installed package, and every template the
submit page offers is a mission the service accepts.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from service_server import serve


@pytest.fixture(scope="module")
def base_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("dashboard-data"), "--workers", "1") as url:
        yield url


@pytest.mark.parametrize(
    ("path", "script"),
    [("/", "runs.js"), ("/submit", "submit.js")],
)
def test_pages_are_served_with_their_scripts(base_url: str, path: str, script: str) -> None:
    page = httpx.get(base_url + path, timeout=10)
    assert page.status_code == 200
    assert page.headers["content-type"].startswith("text/html")
    assert f'src="/static/{script}"' in page.text
    # every local script and stylesheet the page names is served (no CDN, nothing missing)
    for ref in re.findall(r'(?:src|href)="(/static/[^"]+)"', page.text):
        got = httpx.get(base_url + ref, timeout=10)
        assert got.status_code == 200, ref
        assert got.content


def test_pages_name_no_outside_resource(base_url: str) -> None:
    static = Path(__file__).resolve().parents[1] / "src" / "agv_mission" / "service" / "static"
    for path in static.rglob("*"):
        if path.suffix in {".html", ".js", ".css"}:
            assert not re.search(r"https?://", path.read_text()), f"{path.name} loads from the web"


def test_templates_are_the_demo_missions_and_the_service_accepts_each(base_url: str) -> None:
    answer = httpx.get(base_url + "/api/templates", timeout=10)
    assert answer.status_code == 200
    templates = answer.json()["templates"]
    names = [t["name"] for t in templates]
    assert names[:3] == ["patrol", "visit_rooms", "teleop"]
    for template in templates:
        checked = httpx.post(
            base_url + "/api/validate", json={"mission": template["yaml"]}, timeout=30
        )
        assert checked.status_code == 200, (template["name"], checked.text)
        assert checked.json()["ok"] is True


def test_templates_need_the_token_when_one_is_set(tmp_path: Path) -> None:
    with serve(tmp_path, "--token", "s3cret", "--workers", "1") as url:
        assert httpx.get(url + "/api/templates", timeout=10).status_code == 401
        ok = httpx.get(url + "/api/templates", headers={"Authorization": "Bearer s3cret"})
        assert ok.status_code == 200
        # the pages themselves load without it: they ask for ?token= and keep it
        assert httpx.get(url + "/", timeout=10).status_code == 200
