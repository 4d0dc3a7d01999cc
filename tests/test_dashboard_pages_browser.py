"""The dashboard's pages in Debian's chromium at a laptop's and a phone's width (1440 and
390 px), against a real ``agv-mission serve``: a paced run watched, paused, resumed and
repaced on its page; a labelled battery beside progress from the tree; the runs list's
header counts with its table; 404 pages; no console error. Every page is screenshotted
(``$AGV_ARTEFACTS/dashboard-pages`` when set, else the pytest temporary directory)."""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from mission_texts import ENDLESS_PATROL, tb3_mission
from service_server import CHROMIUM, Server, submit, wait_status

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(
        not CHROMIUM.exists(), reason="needs /usr/bin/chromium (apt-get install chromium)"
    ),
]

WIDTHS = {"laptop": (1440, 900), "phone": (390, 844)}
PATROL = tb3_mission(
    ENDLESS_PATROL,
    limits="{time: 600}",
    stack="{localization: {type: ground_truth}, global_planner: {type: grid_astar}}",
    name="watched-patrol",
    robot=None,
)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    with Server(tmp_path_factory.mktemp("pages-serve"), "--workers", "2") as server:
        yield server


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = os.environ.get("AGV_ARTEFACTS")
    folder = Path(root) / "dashboard-pages" if root else tmp_path_factory.mktemp("pages-shots")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture(scope="module")
def watched(service: Server) -> Iterator[str]:
    """A patrol at pace 1 that runs until cancelled: a run a person can watch."""
    with service.client() as client:
        run_id = submit(client, PATROL, pace=1.0)["id"]
        wait_status(client, run_id, {"running"})
        yield run_id
        client.post(f"/api/runs/{run_id}/cancel")


def open_page(browser: Any, width: str, url: str, problems: list[str]) -> Any:
    w, h = WIDTHS[width]
    page = browser.new_context(viewport={"width": w, "height": h}).new_page()
    page.on("pageerror", lambda e: problems.append(f"{page.url}: {e}"))
    page.on("console", lambda m: m.type == "error" and problems.append(f"{page.url}: {m.text}"))
    response = page.goto(url)
    return page, response


@pytest.mark.parametrize("width", WIDTHS)
def test_a_paced_run_on_its_page(
    service: Server, browser: Any, watched: str, shots: Path, width: str
) -> None:
    problems: list[str] = []
    page, _ = open_page(browser, width, f"{service.url}/runs/{watched}", problems)
    page.wait_for_function("() => window.agvRunState().state !== null", timeout=60000)
    # the battery says it is the battery, and is drawn as one; progress comes from the tree
    page.wait_for_selector("#battery:not([hidden])", timeout=30000)
    assert page.inner_text("#battery .label").strip().lower() == "battery"
    assert re.fullmatch(r"\d+\.\d %", page.inner_text("#batterytext").strip())
    page.wait_for_selector("#progress:not([hidden])", timeout=30000)
    assert page.inner_text("#progress .label").strip().lower() == "progress"
    assert re.match(r"\d+/\d+", page.inner_text("#progresstext").strip())
    # the pace the run was submitted with, and a new one chosen on the page
    page.wait_for_function("() => document.getElementById('pace').value === '1'")
    page.select_option("#pace", "4")
    with service.client() as client:
        page.wait_for_function(
            f"async () => (await (await fetch('/api/runs/{watched}')).json()).pace === 4"
        )
        page.screenshot(path=str(shots / f"run-{width}.png"), full_page=width == "phone")
        page.click("#pause")
        wait_status(client, watched, {"paused"})
        page.wait_for_selector("#resume:not([disabled])")
        page.click("#resume")
        wait_status(client, watched, {"running"})
        page.select_option("#pace", "1")
        page.wait_for_function(
            f"async () => (await (await fetch('/api/runs/{watched}')).json()).pace === 1"
        )
    page.context.close()
    assert not problems, problems


@pytest.mark.parametrize("width", WIDTHS)
def test_the_runs_list_counts_with_its_table(
    service: Server, browser: Any, watched: str, shots: Path, width: str
) -> None:
    problems: list[str] = []
    page, _ = open_page(browser, width, f"{service.url}/", problems)
    page.wait_for_selector(f'tr[data-id="{watched}"]')
    # the chips' counts are the table's rows; the top bar's running count (shown on a
    # laptop) is refreshed with the table
    page.wait_for_function(
        """() => {
          const rows = [...document.querySelectorAll('#runs tbody tr')];
          const running = rows.filter((r) => r.dataset.status === 'running').length;
          const chip = document.querySelector('button[data-status="running"] .n');
          const health = document.getElementById('health').textContent;
          return chip && +chip.textContent === running && health.includes(`${running} running`);
        }""",
        timeout=30000,
    )
    page.screenshot(path=str(shots / f"runs-{width}.png"), full_page=width == "phone")
    page.context.close()
    assert not problems, problems


@pytest.mark.parametrize("width", WIDTHS)
def test_the_submit_page_offers_a_pace(
    service: Server, browser: Any, shots: Path, width: str
) -> None:
    problems: list[str] = []
    page, _ = open_page(browser, width, f"{service.url}/submit", problems)
    page.wait_for_function("() => document.getElementById('yaml').value.length > 0")
    options = page.eval_on_selector_all("#pace option", "os => os.map((o) => o.value)")
    assert "" in options and "1" in options
    page.screenshot(path=str(shots / f"submit-{width}.png"), full_page=width == "phone")
    page.context.close()
    assert not problems, problems


@pytest.mark.parametrize("width", WIDTHS)
def test_unknown_runs_and_pages_are_404_pages(
    service: Server, browser: Any, shots: Path, width: str
) -> None:
    for path, says in (("/runs/doesnotexist", "no run doesnotexist"), ("/nowhere", "/nowhere")):
        problems: list[str] = []
        page, response = open_page(browser, width, service.url + path, problems)
        assert response.status == 404
        assert "Not found" in page.inner_text("h1") and says in page.inner_text("#what")
        page.screenshot(path=str(shots / f"404{path.replace('/', '-')}-{width}.png"))
        page.context.close()
        # the document's own 404 is the only console line chromium writes
        assert all("404" in p for p in problems), problems
