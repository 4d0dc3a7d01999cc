"""A fleet on the dashboard, in a real browser (Debian's chromium through Playwright) against
a real `agv-mission serve` process: every robot drawn in its own colour, a robot picked by
its chip or on the map shows its own tree, and a nav goal goes to the picked robot alone.
Screenshots land in ``$AGV_ARTEFACTS/dashboard`` (else the pytest temporary directory)."""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from service_server import CHROMIUM, SHORT_FLEET, TELEOP_FLEET, serve, submit

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(
        not CHROMIUM.exists(),
        reason="browser tests skipped: /usr/bin/chromium is not installed (apt-get install chromium)",
    ),
]

# Pixels of a robot's colour within its footprint (plus its ring and name tag) on the map
# canvas, for every robot: what the user sees, not what the page thinks it drew.
COLOUR_PIXELS = """
() => {
  const view = window.agvView, c = document.getElementById("map");
  const ctx = c.getContext("2d"), dpr = view.dpr || 1;
  const out = {};
  for (const r of Object.values(view.scene.robots)) {
    if (!r.truth) continue;
    const [sx, sy] = view.toScreen(r.truth.x, r.truth.y);
    const half = Math.ceil((Math.max(6, r.radius * view.view.scale) + 4) * dpr);
    const x0 = Math.round(sx * dpr) - half, y0 = Math.round(sy * dpr) - half;
    const px = ctx.getImageData(x0, y0, 2 * half, 2 * half).data;
    const want = [1, 3, 5].map((i) => parseInt(r.colour.slice(i, i + 2), 16));
    const counts = {};
    for (const other of Object.values(view.scene.robots)) {
      const rgb = [1, 3, 5].map((i) => parseInt(other.colour.slice(i, i + 2), 16));
      let n = 0;
      for (let i = 0; i < px.length; i += 4) {
        if (Math.abs(px[i] - rgb[0]) + Math.abs(px[i + 1] - rgb[1]) + Math.abs(px[i + 2] - rgb[2]) < 40) n++;
      }
      counts[other.name] = n;
    }
    out[r.name] = counts;
  }
  return out;
}
"""


@pytest.fixture(scope="module")
def base_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with serve(tmp_path_factory.mktemp("fleet-browser-data"), "--workers", "2") as url:
        yield url


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = os.environ.get("AGV_ARTEFACTS")
    folder = Path(root) / "dashboard" if root else tmp_path_factory.mktemp("fleet-shots")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    context = browser.new_context(viewport={"width": 1400, "height": 860})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    yield page
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


def run_state(page: Any) -> dict[str, Any]:
    return page.evaluate("() => window.agvRunState()")


def _submit(base_url: str, mission: str) -> str:
    with httpx.Client(base_url=base_url, timeout=30.0) as client:
        return submit(client, mission)["id"]


def _robots_drawn(page: Any) -> None:
    page.wait_for_function(
        """() => { const s = window.agvRunState();
                   return s.robots.length === 2 && s.robots.every((r) => r.pose); }""",
        timeout=120_000,
    )
    page.wait_for_timeout(200)  # the next frame is drawn
    pixels = page.evaluate(COLOUR_PIXELS)
    for name, other in (("agv1", "agv2"), ("agv2", "agv1")):
        # its own colour where it stands, hardly the other's
        assert pixels[name][name] >= 30, pixels
        assert pixels[name][name] > 3 * pixels[name][other], pixels


def test_fleet_run_draws_every_robot_and_shows_the_picked_ones_tree(
    page: Any, base_url: str, shots: Path
) -> None:
    run_id = _submit(base_url, SHORT_FLEET)
    page.goto(f"{base_url}/runs/{run_id}")
    page.wait_for_selector('#status[data-status="succeeded"]', timeout=180_000)
    page.wait_for_selector("#replaypanel:not([hidden])", timeout=30_000)
    _robots_drawn(page)
    state = run_state(page)
    assert state["fleet"] and [r["name"] for r in state["robots"]] == ["agv1", "agv2"]
    assert [r["colour"] for r in state["robots"]] == ["#1f77b4", "#d62728"]  # tab:blue, tab:red
    assert all(r["trail"] >= 2 and r["plan"] >= 2 for r in state["robots"])
    assert page.locator("#robotspanel").is_visible()
    assert page.locator("#robots .robotchip").count() == 2
    # the result: each robot's status
    page.wait_for_selector("#resultpanel:not([hidden])")
    assert page.locator('#result .robotresult[data-robot="agv2"]').count() == 1

    # the first robot is picked: its tree; the chip of the second shows the second's
    assert state["selected"] == "agv1"
    agv1_nodes = page.locator("#tree .node").count()
    assert "agv1" in page.inner_text("#treerobot")
    page.click('#robots .robotchip[data-robot="agv2"]')
    page.wait_for_function("() => window.agvRunState().selected === 'agv2'")
    page.wait_for_function(
        f"() => document.querySelectorAll('#tree .node').length !== {agv1_nodes}", timeout=5_000
    )
    assert "agv2" in page.inner_text("#treerobot")
    assert page.locator("#tree .node").count() == len(run_state(page)["tree"])
    assert page.locator("#tree .node.SUCCESS").count() >= 3  # both legs done
    assert "agv2" in page.inner_text("#hud")
    page.screenshot(path=str(shots / "fleet-final.png"))

    # a click on a robot on the map picks it
    agv1 = next(r for r in run_state(page)["robots"] if r["name"] == "agv1")
    sx, sy = page.evaluate(
        f"() => window.agvView.toScreen({agv1['pose']['x']}, {agv1['pose']['y']})"
    )
    page.locator("#map").click(position={"x": sx, "y": sy})
    page.wait_for_function("() => window.agvRunState().selected === 'agv1'")
    page.wait_for_function(  # the panels refresh at 5 Hz
        f"() => document.querySelectorAll('#tree .node').length === {agv1_nodes}", timeout=5_000
    )

    # the replay's event ticks are in the robot's colour
    ticks = page.locator("#ticks i").evaluate_all("ts => ts.map((t) => t.style.background)")
    assert "rgb(214, 39, 40)" in ticks and "rgb(31, 119, 180)" in ticks, ticks
    # the events name their robot in its colour
    rows = page.locator('#events .ev[data-robot="agv2"]')
    assert rows.count() >= 2
    assert "214, 39, 40" in rows.first.get_attribute(
        "style"
    ) or "#d62728" in rows.first.get_attribute("style")


@pytest.mark.slow  # 14 s; test_service_fleet drives the same commands
def test_fleet_teleop_goal_goes_to_the_picked_robot(page: Any, base_url: str, shots: Path) -> None:
    run_id = _submit(base_url, TELEOP_FLEET)
    try:
        page.goto(f"{base_url}/runs/{run_id}")
        page.wait_for_selector('#status[data-status="running"]', timeout=120_000)
        page.wait_for_selector("#teleop.show", timeout=60_000)
        _robots_drawn(page)
        start = {r["name"]: r["pose"] for r in run_state(page)["robots"]}
        page.screenshot(path=str(shots / "fleet-teleop-start.png"))

        # pick agv2 on the map, then a "2D Nav Goal" below it
        a2 = start["agv2"]
        sx, sy = page.evaluate(f"() => window.agvView.toScreen({a2['x']}, {a2['y']})")
        page.locator("#map").click(position={"x": sx, "y": sy})
        page.wait_for_function("() => window.agvRunState().selected === 'agv2'")
        gx, gy = page.evaluate("() => window.agvView.toScreen(1.8, -1.0)")
        page.click("#navgoal")
        page.locator("#map").click(position={"x": gx, "y": gy})
        page.wait_for_function(
            "() => document.getElementById('toast').textContent.includes('goal set')",
            timeout=10_000,
        )
        page.wait_for_function(
            """() => { const r = window.agvRunState().robots.find((r) => r.name === 'agv2');
                       return Math.hypot(r.pose.x - 1.8, r.pose.y + 1.0) < 0.3; }""",
            timeout=120_000,
        )
        page.wait_for_function(  # on the timeline, in agv2's colour
            """() => [...document.querySelectorAll('#events .ev[data-robot="agv2"]')]
                       .some((e) => e.innerText.includes('goal_reached'))""",
            timeout=10_000,
        )
        reached = page.locator("#events .ev[data-robot]", has_text="goal_reached")
        assert reached.count() == 1 and reached.get_attribute("data-robot") == "agv2"
        page.screenshot(path=str(shots / "fleet-teleop-goal.png"))
        a1 = next(r for r in run_state(page)["robots"] if r["name"] == "agv1")["pose"]
        assert math.dist((a1["x"], a1["y"]), (start["agv1"]["x"], start["agv1"]["y"])) < 0.05
        _robots_drawn(page)
    finally:
        httpx.post(f"{base_url}/api/runs/{run_id}/cancel", timeout=10)
