"""``vda5050 watch``: the fleet view of VDA 5050 vehicles on a real broker (Debian's
mosquitto): our simulated vehicle and a minimal one of another manufacturer, read from
their visualization and state, served over HTTP and drawn in a real headless chromium."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from agv_mission.vda5050.body import VehicleWorld
from agv_mission.vda5050.transport import BrokerUrl, free_port
from agv_mission.vda5050.vehicle import Vehicle
from agv_mission.vda5050.vehicle_set import load_vehicles
from agv_mission.vda5050.watch import FleetWatch, WatchServer
from service_server import launch_chromium
from vda5050_peers import MiniMaster, MiniVehicle, Mosquitto, action, edge, node

MAP = "turtlebot3_world"
MISSION = {
    "name": "vda-watch",
    "world": MAP,
    "robot": "burger",
    "start": {"x": -2.0, "y": -0.5, "yaw": 0.0},
    "seed": 2,
    "simulation": {"battery_level": 0.5},
    "stack": {
        "localization": {"type": "ground_truth"},
        "global_planner": {"type": "cost_grid"},
        "local_planner": {"type": "pure_pursuit"},
    },
}


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    folder = tmp_path_factory.mktemp("watch")
    broker = Mosquitto(folder)
    broker.start()
    url = BrokerUrl("127.0.0.1", broker.port)
    path = folder / "vehicle.yaml"
    path.write_text(yaml.safe_dump(MISSION))
    mission = load_vehicles(path)
    world = VehicleWorld(mission.loaded, 5.0)
    body = world.bodies[mission.vehicles[0].robot]
    vehicle = Vehicle(body, mission.vehicles[0].description, url, "agv1", log_dir=folder / "logs")
    body.on_change = vehicle.wake
    world.start()
    assert world.ready.wait(60)
    vehicle.start()
    other = MiniVehicle(broker.port, "forklift1", 1.6, 1.6, MAP, manufacturer="acme")
    master = MiniMaster(broker.port)
    watch = FleetWatch(url)
    watch.start()
    server = WatchServer(watch, "127.0.0.1", 0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield {
        "base": f"http://127.0.0.1:{server.server_address[1]}",
        "master": master,
        "folder": folder,
    }
    server.shutdown()
    server.server_close()
    watch.stop()
    other.close()
    vehicle.stop()
    world.stop()
    master.close()
    broker.stop()
    assert not master.invalid, master.invalid


def fleet(base: str, pred: Any, timeout: float = 30.0) -> dict[str, dict[str, Any]]:
    deadline = time.monotonic() + timeout
    last: dict[str, dict[str, Any]] = {}
    while time.monotonic() < deadline:
        doc = httpx.get(f"{base}/api/vehicles", timeout=5).json()
        last = {v["serial"]: v for v in doc["vehicles"]}
        if pred(last):
            return last
        time.sleep(0.1)
    raise AssertionError(f"the watch did not show it within {timeout} s: {last}")


def test_the_watch_follows_every_vehicle_on_the_broker(rig: dict[str, Any]) -> None:
    base, master = rig["base"], rig["master"]
    seen = fleet(
        base,
        lambda vs: (
            {"agv1", "forklift1"} <= set(vs)
            and vs["agv1"]["position"]
            and vs["agv1"]["battery"] is not None
        ),
    )
    agv = seen["agv1"]
    assert agv["manufacturer"] == "agv-mission" and seen["forklift1"]["manufacturer"] == "acme"
    assert agv["connection"] == "ONLINE" and agv["position"]["mapId"] == MAP
    assert agv["position"]["x"] == pytest.approx(-2.0, abs=0.05)
    assert 40.0 < agv["battery"] <= 50.0 and agv["charging"] is False  # the robot's battery
    # an order: the view shows it driving, its order and the nodes still to go
    a, b = node("s", 0, -2.0, -0.5, MAP), node("t", 2, -1.2, -0.5, MAP)
    master.send("agv1", "order", orderId="w-1", orderUpdateId=0, nodes=[a, b], edges=[edge(a, b)])
    driving = fleet(base, lambda vs: vs["agv1"]["driving"] and vs["agv1"]["order"] == "w-1")
    assert [n["nodeId"] for n in driving["agv1"]["nodes"]] == ["t"]
    assert driving["agv1"]["messages"]["visualization"] >= 1  # fed by both topics
    fleet(base, lambda vs: vs["agv1"]["lastNode"] == "t" and not vs["agv1"]["driving"])
    # an error (charging away from a dock) reaches the view with its level
    master.send("agv1", "instantActions", actions=[action("c1", "startCharging")])
    failed = fleet(
        base, lambda vs: any(e["errorType"] == "chargingError" for e in vs["agv1"]["errors"])
    )
    assert failed["agv1"]["errors"][-1]["errorLevel"] == "WARNING"
    # a map the view knows (the built-in world) and one it does not
    m = httpx.get(f"{base}/api/map", params={"id": MAP}, timeout=10).json()
    assert m["width"] > 0 and m["png"] and [d["name"] for d in m["docks"]] == ["charger"]
    assert httpx.get(f"{base}/api/map", params={"id": "nowhere"}, timeout=10).status_code == 404


def test_the_watch_page_in_chromium(rig: dict[str, Any]) -> None:
    from playwright.sync_api import sync_playwright

    base = rig["base"]
    fleet(base, lambda vs: {"agv1", "forklift1"} <= set(vs))
    root = os.environ.get("AGV_ARTEFACTS")
    shots = Path(root) / "vda5050" if root else rig["folder"]
    shots.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = launch_chromium(p)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 760})
            problems: list[str] = []
            page.on("pageerror", lambda e: problems.append(str(e)))
            page.goto(base + "/")
            page.wait_for_selector('.agv[data-serial="agv1"] .battery', timeout=20000)
            page.wait_for_selector('.agv[data-serial="forklift1"]', timeout=20000)
            page.wait_for_function(
                "() => view.scene.map !== null && view.mapId === 'turtlebot3_world'"
            )
            # the cell is drawn at the first message, the battery at the first state with one
            page.wait_for_function(
                """() => document.querySelector('.agv[data-serial="agv1"] .battery')
                    .textContent.includes('%')""",
                timeout=20000,
            )
            battery = page.inner_text('.agv[data-serial="agv1"] .battery')
            assert "%" in battery and "V" in battery
            assert "acme" in page.inner_text('.agv[data-serial="forklift1"]').lower()
            # agv1 is drawn where its visualization puts it: its colour around that point
            colour = page.evaluate(
                """() => {
                  const v = view.vehicles.find((q) => q.serial === 'agv1');
                  const [x, y] = view.toScreen(v.position.x, v.position.y);
                  const d = view.dpr || 1, r = 6 * d;
                  const px = view.ctx.getImageData(x * d - r, y * d - r, 2 * r, 2 * r).data;
                  const c = [1, 3, 5].map((k) => parseInt(v.color.slice(k, k + 2), 16));
                  let hits = 0;
                  for (let i = 0; i < px.length; i += 4)
                    if (Math.abs(px[i] - c[0]) + Math.abs(px[i + 1] - c[1]) + Math.abs(px[i + 2] - c[2]) < 40) hits++;
                  return hits;
                }"""
            )
            page.screenshot(path=str(shots / "vda5050-watch.png"))
            assert colour > 5, colour
            assert not problems, problems
        finally:
            browser.close()


def test_watch_cli_serves_and_rejects_a_bad_world(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "agv_mission.cli", "vda5050", "watch"]
    r = subprocess.run(
        [*cmd, "--world", str(tmp_path / "nope.yaml"), "--broker", "mqtt://127.0.0.1:1"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "nope.yaml" in r.stderr
    embedded_port, page_port = free_port(), free_port()
    proc = subprocess.Popen(
        [*cmd, "--embedded-port", str(embedded_port), "--port", str(page_port), "--duration", "30"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                doc = httpx.get(f"http://127.0.0.1:{page_port}/api/vehicles", timeout=2).json()
                break
            except httpx.HTTPError:
                assert time.monotonic() < deadline and proc.poll() is None, proc.stderr
                time.sleep(0.2)
        assert doc["vehicles"] == [] and doc["connected"] is True
        html = httpx.get(f"http://127.0.0.1:{page_port}/", timeout=5).text
        assert "mapview.js" in html and "watch.js" in html
        assert "MapView" in httpx.get(f"http://127.0.0.1:{page_port}/static/mapview.js").text
    finally:
        proc.terminate()
        proc.wait(20)
    assert proc.returncode == 0, proc.stderr.read() if proc.stderr else ""


def test_the_watch_page_at_phone_width(rig: dict[str, Any]) -> None:
    """At 390 px the map takes the page's width above the cards (not a squeezed column),
    and a vehicle has its fleet's colour: the first of a manufacturer run.png's first."""
    from playwright.sync_api import sync_playwright

    from agv_mission.missions.report.palette import ROBOT_COLOURS

    base = rig["base"]
    fleet(base, lambda vs: {"agv1", "forklift1"} <= set(vs))
    root = os.environ.get("AGV_ARTEFACTS")
    shots = Path(root) / "vda5050" if root else rig["folder"]
    shots.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = launch_chromium(p)
        try:
            page = browser.new_page(viewport={"width": 390, "height": 844})
            problems: list[str] = []
            page.on("pageerror", lambda e: problems.append(str(e)))
            page.on("console", lambda m: m.type == "error" and problems.append(m.text))
            page.goto(base + "/")
            page.wait_for_selector('.agv[data-serial="agv1"]', timeout=20000)
            box = page.locator("#map").bounding_box()
            cards = page.locator("#fleet").bounding_box()
            assert box is not None and cards is not None
            assert box["width"] >= 300 and box["height"] >= 260, box
            assert cards["y"] >= box["y"] + box["height"] - 1, (box, cards)  # below the map
            colours = page.evaluate("() => view.vehicles.map((v) => [v.serial, v.color])")
            assert dict(colours)["agv1"] == ROBOT_COLOURS[0], colours
            page.screenshot(path=str(shots / "vda5050-watch-390.png"), full_page=True)
            assert not problems, problems
        finally:
            browser.close()
