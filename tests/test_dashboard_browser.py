"""The dashboard in a real browser: Debian's chromium, headless, driven by Playwright, against
a real `agv-mission serve` process. Screenshots of every page are kept as artefacts
(``$AGV_ARTEFACTS/dashboard`` when set, else the pytest temporary directory)."""

from __future__ import annotations

import os
import re
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from service_server import CHROMIUM, serve

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(
        not CHROMIUM.exists(),
        reason="browser tests skipped: /usr/bin/chromium is not installed (apt-get install chromium)",
    ),
]

# Records the map canvas a few times a second while the run is live, so a test can compare
# frames even when the run is over before it looks.
FRAME_SAMPLER = """
window.__frames = [];
setInterval(() => {
  const c = document.getElementById("map");
  const st = window.agvRunState && window.agvRunState();
  if (!c || !st || st.status !== "running" || !st.state || window.__frames.length >= 60) return;
  window.__frames.push({ t: st.state.t, x: st.state.pose.x, y: st.state.pose.y, png: c.toDataURL() });
}, 150);
"""


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("dashboard-browser-data")


@pytest.fixture(scope="module")
def base_url(data_dir: Path) -> Iterator[str]:
    with serve(data_dir, "--workers", "2") as url:
        yield url


@pytest.fixture(scope="module")
def shots(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = os.environ.get("AGV_ARTEFACTS")
    folder = Path(root) / "dashboard" if root else tmp_path_factory.mktemp("dashboard-shots")
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


def wait_status(page: Any, status: str, timeout_s: float = 120.0) -> None:
    page.wait_for_selector(f'#status[data-status="{status}"]', timeout=timeout_s * 1000)


def wait_toast(page: Any, text: str) -> None:
    """The page's confirmation line says ``text`` (earlier toasts may still be showing)."""
    page.wait_for_function(
        "(text) => document.getElementById('toast').textContent.includes(text)",
        arg=text,
        timeout=10_000,
    )
    assert "good" in page.get_attribute("#toast", "class")


def test_submit_the_demo_patrol_and_watch_it_succeed(page: Any, base_url: str, shots: Path) -> None:
    page.add_init_script(FRAME_SAMPLER)
    page.goto(base_url + "/submit")
    page.wait_for_selector('#template option[value="patrol"]', state="attached")
    page.select_option("#template", "patrol")
    page.wait_for_selector("#checkstate .okline", timeout=30_000)
    assert "tb3-patrol" in page.inner_text("#checks")
    page.screenshot(path=str(shots / "submit.png"))

    page.click("#submit")
    page.wait_for_url(re.compile(r"/runs/[^/]+$"), timeout=30_000)
    run_id = page.url.rsplit("/", 1)[1]
    wait_status(page, "succeeded", timeout_s=240)

    # the canvas showed the robot moving: frames taken while it ran differ, as do its poses
    frames = page.evaluate("() => window.__frames")
    assert len(frames) >= 2, "the page saw fewer than two frames of the running patrol"
    assert len({f["png"] for f in frames}) >= 2
    assert max(f["t"] for f in frames) > min(f["t"] for f in frames)
    moved = max(abs(a["x"] - b["x"]) + abs(a["y"] - b["y"]) for a in frames for b in frames)
    assert moved > 0.05

    # the end: result summary, file links, the tree with its final statuses, the replay slider
    page.wait_for_selector("#resultpanel:not([hidden])")
    result_text = page.inner_text("#result")
    assert "succeeded" in result_text
    assert "result.json" in result_text and "run.png" in result_text
    assert page.locator("#tree .node.SUCCESS").count() >= 1
    assert page.locator("#events .ev").count() >= 1
    page.wait_for_selector("#replaypanel:not([hidden])", timeout=30_000)
    page.wait_for_function("() => window.agvView.scene.map && window.agvView.scene.truth")
    page.screenshot(path=str(shots / "run-final.png"))

    # scrub back to the middle of the run: the robot is elsewhere and the canvas changes
    end_state = run_state(page)
    end_png = page.evaluate("() => document.getElementById('map').toDataURL()")
    middle = (end_state["replay"]["t0"] + end_state["replay"]["t1"]) / 2
    page.evaluate(
        """(t) => { const s = document.getElementById('scrub');
                    s.value = t; s.dispatchEvent(new Event('input')); }""",
        middle,
    )
    page.wait_for_timeout(300)
    mid_state = run_state(page)
    assert abs(mid_state["state"]["t"] - middle) < 1.0
    assert mid_state["state"]["pose"] != end_state["state"]["pose"]
    assert page.evaluate("() => document.getElementById('map').toDataURL()") != end_png
    assert page.locator("#events .ev.future").count() >= 1
    page.screenshot(path=str(shots / "run-replay.png"))

    # the runs page lists it, with the succeeded filter
    page.goto(base_url + "/")
    row = page.locator(f'tr[data-id="{run_id}"]')
    row.wait_for()
    assert row.get_attribute("data-status") == "succeeded"
    page.click('button[data-status="succeeded"]')
    assert page.locator("tbody tr").count() >= 1
    assert all(
        s == "succeeded"
        for s in page.locator("tbody tr").evaluate_all("rows => rows.map(r => r.dataset.status)")
    )
    page.wait_for_function(
        f"() => document.querySelector('tr[data-id=\"{run_id}\"]').innerText.includes('turtlebot3_world')",
        timeout=15_000,
    )
    page.screenshot(path=str(shots / "runs.png"))


def test_submit_page_shows_errors_beside_their_lines_and_takes_overrides(
    page: Any, base_url: str, shots: Path
) -> None:
    page.goto(base_url + "/submit")
    page.wait_for_selector('#template option[value="patrol"]', state="attached")
    page.select_option("#template", "patrol")
    page.wait_for_selector("#checkstate .okline", timeout=30_000)
    text = page.input_value("#yaml")
    line = text.splitlines().index("    loops: 2") + 1
    page.fill("#yaml", text.replace("    loops: 2", "    loops: -1"))
    # the service's problem shows beside its line, with the field, and in the list
    mark = page.locator(f'#marks div[data-line="{line}"]')
    mark.wait_for(timeout=30_000)
    assert "tasks.0.loops" in mark.inner_text()  # spelled as the command line spells it
    assert "greater than or equal to 1" in mark.inner_text()
    assert page.locator("#gutter div.err").first.inner_text() == str(line)
    assert f"line {line}" in page.inner_text("#checks")
    page.screenshot(path=str(shots / "submit-error.png"))
    # a --set override fixes it: the same text is then accepted
    page.fill("#overrides", "tasks.0.loops=1")
    page.wait_for_selector("#checkstate .okline", timeout=30_000)
    assert page.locator("#marks div").count() == 0
    # an override naming an unknown plugin is refused, naming the field
    page.fill("#overrides", "tasks.0.loops=1\nstack.local_planner.type=warp")
    page.wait_for_function(
        "() => document.getElementById('checks').innerText.includes('stack.local_planner')",
        timeout=30_000,
    )
    assert "warp" in page.inner_text("#checks")


def _submit_teleop(base_url: str) -> str:
    templates = httpx.get(base_url + "/api/templates", timeout=10).json()["templates"]
    teleop = next(t["yaml"] for t in templates if t["name"] == "teleop")
    answer = httpx.post(base_url + "/api/runs", json={"mission": teleop}, timeout=30)
    assert answer.status_code == 201, answer.text
    return answer.json()["id"]


def test_teleop_from_the_page_pause_resume_record_goal_cancel(
    page: Any, base_url: str, shots: Path
) -> None:
    run_id = _submit_teleop(base_url)
    page.goto(f"{base_url}/runs/{run_id}")
    wait_status(page, "running", timeout_s=120)
    page.wait_for_selector("#teleop.show", timeout=60_000)
    page.wait_for_function("() => window.agvView.scene.map && window.agvView.scene.truth")

    # drive forward with the arrow key: the true pose moves
    start = run_state(page)["state"]["pose"]
    page.locator("#map").click(position={"x": 5, "y": 5})  # focus the page, not an input
    page.keyboard.down("ArrowUp")
    page.wait_for_function(
        f"""() => {{ const p = window.agvRunState().state.pose;
                    return Math.hypot(p.x - {start["x"]}, p.y - {start["y"]}) > 0.1; }}""",
        timeout=20_000,
    )
    page.keyboard.up("ArrowUp")
    # and turn with the on-screen pad
    yaw0 = run_state(page)["state"]["pose"]["yaw"]
    pad = page.locator('#pad button[data-key="ArrowLeft"]')
    pad.dispatch_event("pointerdown")
    page.wait_for_function(
        f"() => Math.abs(window.agvRunState().state.pose.yaw - ({yaw0})) > 0.1", timeout=20_000
    )
    pad.dispatch_event("pointerup")

    # pause: the status says so and simulated time holds; resume: it moves on
    page.click("#pause")
    wait_status(page, "paused", timeout_s=10)
    page.wait_for_timeout(500)
    held = run_state(page)["state"]["t"]
    page.wait_for_timeout(1000)
    assert run_state(page)["state"]["t"] == pytest.approx(held, abs=0.15)
    assert run_state(page)["status"] == "paused"
    page.click("#resume")
    wait_status(page, "running", timeout_s=10)
    page.wait_for_function(f"() => window.agvRunState().state.t > {held} + 0.3", timeout=20_000)

    # record a room: the label prompt, the service's confirmation, the entry on the map
    page.click("#record")
    page.fill("#reclabel", "livingroom")
    page.press("#reclabel", "Enter")
    wait_toast(page, "Entry saved in file")
    page.wait_for_function("() => !!window.agvView.scene.recorded.livingroom", timeout=10_000)

    # the seed's "2D Nav Goal": click the map half a metre behind the robot
    pose = run_state(page)["state"]["pose"]
    sx, sy = page.evaluate(f"() => window.agvView.toScreen({pose['x']} - 0.5, {pose['y']})")
    page.click("#navgoal")
    page.locator("#map").click(position={"x": sx, "y": sy})
    wait_toast(page, "goal set")
    goal = page.evaluate("() => window.agvView.scene.goal")
    assert goal["x"] == pytest.approx(pose["x"] - 0.5, abs=0.1)
    page.screenshot(path=str(shots / "run-teleop.png"))

    # cancel (two presses, so a stray tap does not end a run): aborted, with its recorder file
    page.click("#cancel")
    page.click("#cancel")
    wait_status(page, "aborted", timeout_s=60)
    page.wait_for_selector("#resultpanel:not([hidden])")
    page.wait_for_function(
        "() => document.getElementById('result').innerText.includes('location_recorder.yaml')",
        timeout=20_000,
    )
    recorder = httpx.get(f"{base_url}/api/runs/{run_id}/files/location_recorder.yaml", timeout=10)
    assert recorder.status_code == 200
    assert "livingroom" in recorder.text


def test_a_ros_map_is_shown_at_readable_scale(
    page: Any, base_url: str, data_dir: Path, ros_maps: Path, shots: Path
) -> None:
    # missions from HTTP read files under --data only: the test puts the real map there
    folder = data_dir / "maps" / "aws_small_house"
    shutil.copytree(ros_maps / "aws_small_house", folder, dirs_exist_ok=True)
    mission = (
        f"name: aws-house\nworld: {folder / 'map.yaml'}\nrobot: burger\n"
        "tasks:\n  - {type: teleop, duration: 60}\n"
    )
    answer = httpx.post(base_url + "/api/runs", json={"mission": mission}, timeout=30)
    assert answer.status_code == 201, answer.text
    run_id = answer.json()["id"]
    page.goto(f"{base_url}/runs/{run_id}")
    page.wait_for_function(
        "() => window.agvView.scene.map && window.agvView.scene.truth", timeout=120_000
    )
    view = page.evaluate(
        """() => { const v = window.agvView, k = v.scene.map.known;
                   return {scale: v.view.scale, W: v.W, H: v.H, known: k,
                           width: v.scene.map.width * v.scene.map.resolution}; }"""
    )
    x0, y0, x1, y1 = view["known"]
    # the 25 m grid is mostly unknown: the view frames the house itself, filling the canvas
    assert x1 - x0 < view["width"]
    fill = max((x1 - x0) * view["scale"] / view["W"], (y1 - y0) * view["scale"] / view["H"])
    assert fill > 0.9
    assert view["scale"] >= 25  # pixels per metre: a 0.2 m robot is 5 px or more
    page.screenshot(path=str(shots / "run-aws-small-house.png"))
    httpx.post(f"{base_url}/api/runs/{run_id}/cancel", timeout=10)


def test_pages_work_with_a_token(page: Any, tmp_path: Path) -> None:
    with serve(tmp_path, "--token", "s3cret", "--workers", "1") as url:
        page.goto(url + "/")
        page.wait_for_function(
            "() => document.getElementById('health').textContent.includes('token needed')"
        )
        page.goto(url + "/?token=s3cret")  # once: the pages keep it
        page.wait_for_function(
            "() => document.getElementById('health').textContent.includes('workers')"
        )
        page.goto(url + "/submit")
        page.wait_for_selector('#template option[value="patrol"]', state="attached")
        page.wait_for_selector("#checkstate .okline", timeout=30_000)


def test_phone_layout_has_no_sideways_scroll(browser: Any, base_url: str, shots: Path) -> None:
    context = browser.new_context(
        viewport={"width": 390, "height": 844},
        device_scale_factor=2,
        is_mobile=True,
        has_touch=True,
    )
    page = context.new_page()
    try:
        runs = httpx.get(base_url + "/api/runs", timeout=10).json()["runs"]
        targets = [("runs-phone", "/"), ("submit-phone", "/submit")]
        if runs:
            targets.append(("run-phone", f"/runs/{runs[0]['id']}"))
        for name, path in targets:
            page.goto(base_url + path)
            page.wait_for_load_state("networkidle")
            time.sleep(0.5)
            width = page.evaluate("() => document.documentElement.scrollWidth")
            assert width <= 391, f"{path} scrolls sideways on a phone ({width} px)"
            page.screenshot(path=str(shots / f"{name}.png"), full_page=True)
    finally:
        context.close()


BATTERY_SAMPLER = """
window.__battery = [];
setInterval(() => {
  const box = document.getElementById("battery");
  if (!box || box.hidden) return;
  window.__battery.push({
    value: +box.dataset.level,
    label: box.querySelector(".label").textContent,
    text: document.getElementById("batterytext").textContent,
    charging: box.classList.contains("charging"),
  });
}, 100);
"""


@pytest.mark.slow  # 15 s; the battery itself is test_battery's
def test_run_page_shows_the_battery_level_and_charging(
    page: Any, base_url: str, shots: Path
) -> None:
    mission = (
        "name: dock-and-charge\nworld: turtlebot3_world\nrobot: burger\n"
        "start: {x: -2.0, y: -0.5, yaw: 0.0}\nsimulation: {battery_level: 0.5}\n"
        "stack: {localization: {type: ground_truth}}\n"
        "tasks:\n  - {type: dock}\n  - {type: charge, until: 0.6}\n  - {type: undock}\n"
    )
    answer = httpx.post(base_url + "/api/runs", json={"mission": mission}, timeout=30)
    assert answer.status_code == 201, answer.text
    page.add_init_script(BATTERY_SAMPLER)
    page.goto(f"{base_url}/runs/{answer.json()['id']}")
    page.wait_for_selector("#battery:not([hidden])", timeout=60_000)
    page.wait_for_selector("#battery.charging", timeout=120_000)
    page.screenshot(path=str(shots / "run-battery-charging.png"))
    docks = page.evaluate("() => window.agvView.scene.docks")
    assert [(d["name"], d["x"], d["y"]) for d in docks] == [("charger", 0.55, -2.2)]
    wait_status(page, "succeeded", timeout_s=180)
    seen = page.evaluate("() => window.__battery")
    values = [s["value"] for s in seen]
    assert all(0.45 < v <= 0.61 for v in values)
    assert values[0] == pytest.approx(0.5, abs=0.005)  # the start: 50 %
    assert re.fullmatch(r"\d+\.\d %( · docked at charger)?", seen[-1]["text"])
    charging = [s["value"] for s in seen if s["charging"]]
    assert all("docked at charger" in s["text"] for s in seen if s["charging"])
    assert charging and max(charging) > min(charging)  # it rose while charging
    final = run_state(page)["state"]
    assert final["battery"] == pytest.approx(
        page.evaluate("() => +document.getElementById('battery').dataset.level")
    )
    assert all(s["label"].strip().lower() == "battery" for s in seen)  # said, not guessed


def test_run_page_draws_the_people(page: Any, base_url: str, shots: Path) -> None:
    """People wandering the living room reach the page (live, and in the replay of the
    finished run) and are drawn on the map: the people layer changes the picture."""
    mission = (
        "name: people-walk\nworld: small_house\nrobot: burger\n"
        "start: {x: -1.5, y: -2.0, yaw: 0.0}\nstack: {localization: {type: ground_truth}}\n"
        "people:\n  - {count: 3, area: livingroom}\n"
        "tasks:\n  - {type: go_to, pose: {x: 3.5, y: -2.0, yaw: 0.0}}\nlimits: {time: 30.0}\n"
    )
    answer = httpx.post(base_url + "/api/runs", json={"mission": mission}, timeout=30)
    assert answer.status_code == 201, answer.text
    page.goto(f"{base_url}/runs/{answer.json()['id']}")
    page.wait_for_function("() => (window.agvView.scene.people || []).length === 3", timeout=90_000)
    page.wait_for_function(  # over (however the robot fared): the replay is shown
        "() => ['succeeded', 'failed'].includes(document.getElementById('status').dataset.status)",
        timeout=120_000,
    )
    page.wait_for_function("() => (window.agvView.scene.people || []).length === 3", timeout=30_000)
    people = page.evaluate("() => window.agvView.scene.people")
    assert [p[0] for p in people] == [0, 1, 2]
    assert all(-2.3 - 0.3 < p[1] < 4.6 + 0.3 and -5.3 - 0.3 < p[2] < 0.3 for p in people)
    page.evaluate("() => window.agvView.fit()")
    page.screenshot(path=str(shots / "run-people.png"))
    shown = page.evaluate("() => document.getElementById('map').toDataURL()")
    page.evaluate("() => { document.querySelector('input[data-layer=people]').click(); }")
    page.wait_for_timeout(300)
    hidden = page.evaluate("() => document.getElementById('map').toDataURL()")
    assert shown != hidden  # the discs were on the map
