"""``/docs`` in a real browser with no network beyond the service: Debian's chromium,
headless, driven by Playwright, against a real ``agv-mission serve`` process. Every request
to another host is aborted (and counted), so a page that needed a CDN would fail here.
The screenshot is kept (``$AGV_ARTEFACTS/docs`` when set, else pytest's temporary dir)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

from service_server import CHROMIUM, launch_chromium, serve

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(
        not CHROMIUM.exists(),
        reason="browser tests skipped: /usr/bin/chromium is not installed (apt-get install chromium)",
    ),
]


def test_docs_render_every_operation_offline_and_try_it_out_works(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    from playwright.sync_api import sync_playwright

    root = os.environ.get("AGV_ARTEFACTS")
    shots = Path(root) / "docs" if root else tmp_path_factory.mktemp("docs-shots")
    shots.mkdir(parents=True, exist_ok=True)
    with serve(tmp_path_factory.mktemp("docs-data"), "--workers", "1") as url:
        own = urlsplit(url).netloc
        with sync_playwright() as p:
            browser = launch_chromium(p)
            context = browser.new_context(viewport={"width": 1300, "height": 1400})
            outside: list[str] = []

            def route(r: Any) -> None:
                if urlsplit(r.request.url).netloc == own:
                    r.continue_()
                else:
                    outside.append(r.request.url)
                    r.abort()

            context.route("**/*", route)
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(url + "/docs")
            page.wait_for_selector(".opblock", timeout=30_000)
            page.screenshot(path=str(shots / "docs-top.png"))
            paths = page.locator(".opblock-summary-path").all_inner_texts()
            paths = [p.replace("\u200b", "").strip() for p in paths]
            for path in ("/api/health", "/api/runs", "/api/runs/{run_id}/goal"):
                assert path in paths, paths
            assert len(paths) >= 12
            assert page.locator(".models, section.models").count() >= 1  # the schemas

            health = page.locator(".opblock-get", has_text="/api/health").first
            health.locator(".opblock-summary").click()
            health.locator("button.try-out__btn").click()
            health.locator("button.execute").click()
            status = health.locator(".live-responses-table tr.response .response-col_status").first
            status.wait_for(timeout=30_000)
            assert status.inner_text().strip().startswith("200")
            assert '"status": "ok"' in health.locator(".live-responses-table").inner_text()

            submit = page.locator(".opblock-post", has_text="/api/runs").first
            submit.locator(".opblock-summary").click()
            submit.locator(".body-param-content-type select, .content-type").first.wait_for()
            media = submit.locator(".body-param-content-type select option").all_inner_texts()
            assert {"application/json", "application/yaml"} <= set(media)
            page.screenshot(path=str(shots / "docs.png"), full_page=False)
            context.close()
            browser.close()
    assert not outside, f"the docs asked another host: {outside}"
    assert not errors, f"JavaScript errors on the page: {errors}"
