"""agv-mission serve end to end: a real server process, real HTTP and WebSocket clients."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import httpx
import pytest
import websockets
import yaml

from cli_in_process import agv
from service_server import (
    AGV,
    FINAL,
    SHORT_FLEET,
    SHORT_MISSION,
    WANDER_MISSION,
    Server,
    collect_live,
    submit,
    wait_status,
)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    with Server(tmp_path_factory.mktemp("svc") / "data", "--workers", "2") as srv:
        yield srv


@pytest.fixture
def client(server: Server):
    with server.client() as c:
        yield c


def test_submit_follow_files(server: Server, client: httpx.Client) -> None:
    health = client.get("/api/health").json()
    assert health["status"] == "ok" and health["workers"] == 2
    run = submit(client, SHORT_MISSION)
    assert run["status"] == "queued" and run["name"] == "short"
    messages = asyncio.run(collect_live(f"{server.ws_url}/api/runs/{run['id']}/live"))
    kinds = [m["type"] for m in messages]
    assert kinds[-1] == "end" and messages[-1]["status"] == "succeeded"
    assert {"map", "rooms", "tree", "plan", "state"} <= set(kinds)
    states = [m for m in messages if m["type"] == "state"]
    for key in ("t", "pose", "estimate", "v", "w", "status", "task", "progress"):
        assert key in states[0]
    sim_end = messages[-1]["result"]["sim_time"]
    assert len(states) >= 5 * sim_end * 0.9  # at least 5 per simulated second
    # the battery (the burger's): draining, its last level the result's end level
    levels = [m["battery"] for m in states]
    assert 0.99 < levels[0] <= 1.0  # a client that connects late starts at the current state
    assert all(b <= a for a, b in zip(levels, levels[1:], strict=False))
    end = messages[-1]["result"]["metrics"]["battery"]["end"]
    assert levels[-1] == pytest.approx(end, abs=1e-4) and levels[-1] < 1.0  # within 0.5 s
    assert not any(m["charging"] for m in states) and states[-1]["docked"] is None
    [rooms] = [m for m in messages if m["type"] == "rooms"]
    assert [d["name"] for d in rooms["docks"]] == ["charger"]
    assert any(m["type"] == "event" and m["event"] == "goal_reached" for m in messages)

    final = client.get(f"/api/runs/{run['id']}").json()
    assert final["status"] == "succeeded" and final["result"]["status"] == "succeeded"
    assert final["started"] and final["ended"] and final["created"]
    assert final["progress"]["sim_time"] == pytest.approx(sim_end, abs=0.2)
    files = client.get(f"/api/runs/{run['id']}/files").json()["files"]
    assert {"result.json", "run.png", "mission.yaml", "stream.jsonl", "trajectory.csv"} <= set(
        files
    )
    png = client.get(f"/api/runs/{run['id']}/files/run.png")
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert client.get(f"/api/runs/{run['id']}/files/result.json").json()["status"] == "succeeded"
    assert client.get(f"/api/runs/{run['id']}/files/..%2Fregistry.sqlite3").status_code == 404
    assert client.get(f"/api/runs/{run['id']}/files/nothing.txt").status_code == 404
    stream = client.get(f"/api/runs/{run['id']}/files/stream.jsonl").text.splitlines()
    assert json.loads(stream[-1])["type"] == "end"
    listed = client.get("/api/runs", params={"status": "succeeded"}).json()["runs"]
    assert run["id"] in [r["id"] for r in listed]
    assert client.get("/api/runs/nope").status_code == 404
    assert client.post(f"/api/runs/{run['id']}/cancel").status_code == 409
    assert client.post(f"/api/runs/{run['id']}/pause").status_code == 409
    goal = client.post(f"/api/runs/{run['id']}/goal", json={"x": 0, "y": 0, "yaw": 0})
    assert goal.status_code == 409  # only a running teleop task takes goals
    assert client.post(f"/api/runs/{run['id']}/rooms/kitchen").status_code == 409

    # a late client of a finished run: the snapshot, then the end
    late = asyncio.run(collect_live(f"{server.ws_url}/api/runs/{run['id']}/live"))
    assert [m["type"] for m in late][:3] == ["map", "rooms", "recorded"]
    assert late[-1]["type"] == "end" and late[-1]["status"] == "succeeded"


TREE_MISSION = """\
name: short-tree
world: turtlebot3_world
start: {x: -2.0, y: -0.5, yaw: 0.0}
stack: {localization: {type: ground_truth}, global_planner: {type: grid_astar}}
tree:
  type: sequence
  children:
    - {type: go_to, pose: {x: -1.5, y: -0.5, yaw: 0.0}}
    - {type: wait, seconds: 0.5}
limits: {time: 30}
"""


def test_a_tree_and_a_fleet_succeed_and_every_file_is_listed_and_served(
    client: httpx.Client,
) -> None:
    """A YAML tree and a fleet submitted as they are; each run lists every file of its
    directory, its bag's too, and serves each one by the listed path (the bag also whole,
    as a zip); nothing outside the run directory."""
    import io
    import zipfile

    runs = [submit(client, TREE_MISSION), submit(client, SHORT_FLEET)]
    for run in runs:
        final = wait_status(client, run["id"], FINAL)
        assert final["status"] == "succeeded", final.get("reason")
        base = f"/api/runs/{run['id']}/files"
        files = client.get(base).json()["files"]
        assert {"result.json", "mission.yaml", "bag/metadata.yaml"} <= set(files), files
        [mcap] = [f for f in files if f.startswith("bag/") and f.endswith(".mcap")]
        body = client.get(f"{base}/{mcap}")
        assert body.status_code == 200 and body.content[:5] == b"\x89MCAP"
        meta = yaml.safe_load(client.get(f"{base}/bag/metadata.yaml").text)
        assert meta["rosbag2_bagfile_information"]["storage_identifier"] == "mcap"
        for name in files:  # every listed file is served
            assert client.get(f"{base}/{name}").status_code == 200, name
        whole = client.get(f"{base}/bag")
        assert whole.headers["content-type"] == "application/zip"
        names = zipfile.ZipFile(io.BytesIO(whole.content)).namelist()
        assert sorted(names) == sorted(f for f in files if f.startswith("bag/"))
        for bad in (
            "bag/..%2F..%2Fregistry.sqlite3",
            "bag/%2E%2E/result.json",
            ".hidden",
            "bag//x",
        ):
            assert client.get(f"{base}/{bad}").status_code == 404, bad


def test_invalid_mission_422_names_line_and_field(client: httpx.Client) -> None:
    bad = SHORT_MISSION.replace("x: -1.5", "x: fast")
    response = client.post("/api/runs", json={"mission": bad})
    assert response.status_code == 422
    errors = response.json()["errors"]
    assert errors[0]["field"] == "tasks.0.pose.x"  # the command line's spelling, everywhere
    assert errors[0]["line"] == 6
    yaml_body = client.post("/api/runs", content=bad, headers={"Content-Type": "application/yaml"})
    assert yaml_body.status_code == 422
    override = client.post("/api/runs", json={"mission": SHORT_MISSION, "set": ["limits.time=-1"]})
    assert override.status_code == 422 and "limits.time" in override.json()["errors"][0]["field"]
    valid = client.post("/api/validate", json={"mission": SHORT_MISSION})
    assert valid.status_code == 200 and valid.json()["mission"]["name"] == "short"
    assert client.post("/api/validate", json={"mission": bad}).status_code == 422
    # validate reads a body as submit does: YAML must be UTF-8, other media types are refused
    for route in ("/api/validate", "/api/runs"):
        latin1 = client.post(route, content=b"name: \xe9", headers={"Content-Type": "text/yaml"})
        assert latin1.status_code == 422, route
        plain = client.post(route, content=SHORT_MISSION, headers={"Content-Type": "text/plain"})
        assert plain.status_code == 415, route


def test_missions_may_read_only_builtins_and_data(server: Server, client: httpx.Client) -> None:
    outside = server.data.parent / "outside"
    outside.mkdir(exist_ok=True)
    (outside / "rooms.yaml").write_text("rooms: {}\n")
    (server.data / "link.yaml").unlink(missing_ok=True)
    (server.data / "link.yaml").symlink_to(outside / "rooms.yaml")
    (server.data / "rooms_ok.yaml").write_text(
        "rooms:\n  corner:\n    polygon: [[-2.5, -1], [-1.5, -1], [-1.5, 0], [-2.5, 0]]\n"
    )
    cases = {
        "world": "world: /etc/passwd",
        "rooms": "rooms: ../outside/rooms.yaml",
        "robot": "robot: /etc/hostname",
    }
    for field, line in cases.items():
        text = SHORT_MISSION.replace("name: short", f"name: short\n{line}")
        response = client.post("/api/runs", json={"mission": text})
        assert response.status_code == 422, (field, response.text)
        assert response.json()["errors"][0]["field"] == field
        assert "root:" not in response.text  # nothing of the file leaks
    linked = SHORT_MISSION.replace("name: short", "name: short\nrooms: link.yaml")
    response = client.post("/api/runs", json={"mission": linked})
    assert response.status_code == 422 and response.json()["errors"][0]["field"] == "rooms"
    via_set = client.post(
        "/api/runs", json={"mission": SHORT_MISSION, "set": ["world=/etc/passwd"]}
    )
    assert via_set.status_code == 422 and via_set.json()["errors"][0]["field"] == "world"
    ok = SHORT_MISSION.replace("name: short", "name: short\nrooms: rooms_ok.yaml")
    assert client.post("/api/validate", json={"mission": ok}).status_code == 200
    tagged = "!!python/object/apply:os.system ['touch /tmp/agv-pwned']\n" + SHORT_MISSION
    assert client.post("/api/runs", json={"mission": tagged}).status_code == 422
    assert not Path("/tmp/agv-pwned").exists()


def test_bodies_are_bounded_and_typed(client: httpx.Client) -> None:
    huge = "# " + "x" * 1_100_000 + "\n" + SHORT_MISSION
    assert client.post("/api/runs", json={"mission": huge}).status_code == 413
    plain = client.post("/api/runs", content=SHORT_MISSION, headers={"Content-Type": "text/plain"})
    assert plain.status_code == 415
    cross = client.post(
        "/api/runs",
        json={"mission": SHORT_MISSION},
        headers={"Origin": "http://evil.example"},
    )
    assert cross.status_code == 403
    assert "access-control-allow-origin" not in {k.lower() for k in cross.headers}


def test_pause_resume_cancel(server: Server, client: httpx.Client) -> None:
    run = submit(client, WANDER_MISSION % {"duration": 600})
    rid = run["id"]
    wait_status(client, rid, {"running"})
    while client.get(f"/api/runs/{rid}").json()["progress"]["sim_time"] < 1.0:
        time.sleep(0.05)
    assert client.post(f"/api/runs/{rid}/resume").status_code == 409
    assert client.post(f"/api/runs/{rid}/pause").status_code == 202
    paused = wait_status(client, rid, {"paused"})
    assert client.post(f"/api/runs/{rid}/pause").status_code == 409

    async def while_paused() -> tuple[list[dict], dict]:
        async with websockets.connect(f"{server.ws_url}/api/runs/{rid}/live") as ws:
            await ws.send(json.dumps({"type": "ping"}))
            first: list[dict] = []
            while True:  # the snapshot (a paused run sends nothing else), then the pong
                m = json.loads(await ws.recv())
                if m["type"] == "pong":
                    return first, m
                first.append(m)

    first, pong = asyncio.run(while_paused())
    assert pong == {"type": "pong"}
    state = next(m for m in first if m["type"] == "state")
    assert state["status"] == "paused"
    held = client.get(f"/api/runs/{rid}").json()["progress"]["sim_time"]
    time.sleep(0.5)
    assert client.get(f"/api/runs/{rid}").json()["progress"]["sim_time"] == held
    assert held >= paused["progress"]["sim_time"]
    assert client.post(f"/api/runs/{rid}/resume").status_code == 202
    wait_status(client, rid, {"running"})
    while client.get(f"/api/runs/{rid}").json()["progress"]["sim_time"] <= held + 0.5:
        time.sleep(0.05)
    assert client.post(f"/api/runs/{rid}/cancel").status_code == 202
    final = wait_status(client, rid, FINAL)
    assert final["status"] == "aborted" and final["result"]["status"] == "aborted"
    assert "cancel" in final["reason"]


def test_worker_kill_9_is_an_error_not_a_crash(server: Server, client: httpx.Client) -> None:
    run = submit(client, WANDER_MISSION % {"duration": 600})
    wait_status(client, run["id"], {"running"})
    pid = None
    for _ in range(200):
        pid = _worker_pid(server.data, run["id"])
        if pid:
            break
        time.sleep(0.05)
    assert pid
    os.kill(pid, signal.SIGKILL)
    final = wait_status(client, run["id"], FINAL)
    assert final["status"] == "error" and "SIGKILL" in final["reason"]
    assert client.get("/api/health").json()["status"] == "ok"
    after = submit(client, SHORT_MISSION)
    assert wait_status(client, after["id"], FINAL)["status"] == "succeeded"


def _worker_pid(data: Path, run_id: str) -> int | None:
    import sqlite3

    with sqlite3.connect(data / "registry.sqlite3") as db:
        row = db.execute("SELECT worker_pid FROM runs WHERE id = ?", (run_id,)).fetchone()
    return row[0] if row else None


def test_submit_cli_follow_and_exit_codes(server: Server, tmp_path: Path) -> None:
    mission = tmp_path / "short.yaml"
    mission.write_text(SHORT_MISSION)
    done = subprocess.run(
        [AGV, "submit", str(mission), "--server", server.url, "--follow"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    run_id = done.stdout.splitlines()[0].strip()
    assert len(run_id) == 12 and "succeeded" in done.stdout
    # The same command called in this process (the first submit above started the program).
    failing = agv(
        "submit", str(mission), "--server", server.url, "--follow", "--set", "limits.time=1"
    )
    assert failing.returncode == 1 and "time limit" in failing.stdout
    bad = tmp_path / "bad.yaml"
    bad.write_text(SHORT_MISSION.replace("x: -1.5", "x: fast"))
    invalid = agv("submit", str(bad), "--server", server.url)
    assert invalid.returncode == 2
    assert f"{bad}:6" in invalid.stderr and "pose.x" in invalid.stderr


@pytest.mark.slow
def test_teleop_seed_003_records_four_rooms(server: Server, client: httpx.Client) -> None:
    """Seed 003 over the API: spawn in the living room, go into each room, record it."""
    _teleop_rooms(server, client, ["livingroom", "kitchen", "recreationroom", "bedroom"])


@pytest.mark.slow  # 22 s; the dashboard's teleop test drives the same endpoints
def test_teleop_drive_and_record_two_rooms(server: Server, client: httpx.Client) -> None:
    """The fast part of seed 003: remote driving, a goal, two rooms recorded."""
    _teleop_rooms(server, client, ["livingroom", "kitchen"])


ANCHORS = {
    "livingroom": (3.0, -2.0),
    "kitchen": (7.0, -2.0),
    "recreationroom": (-0.5, 1.8),
    "bedroom": (-4.5, -2.5),
}


def _teleop_rooms(server: Server, client: httpx.Client, labels: list[str]) -> None:
    mission = (
        "name: seed-003\nworld: small_house\nstart: livingroom\n"
        "stack: {localization: {type: amcl}}\ntasks:\n  - {type: teleop}\n"
    )
    run = submit(client, mission)
    rid = run["id"]
    wait_status(client, rid, {"running"})
    anchors = {label: ANCHORS[label] for label in labels}
    replies = asyncio.run(_seed_003(server, rid, anchors))
    for label, (x, y) in anchors.items():
        body = replies[label]
        assert body["confirmation"] == "Entry saved in file" and body["label"] == label
        assert abs(body["pose"]["x"] - x) < 0.3 and abs(body["pose"]["y"] - y) < 0.3

    doc = yaml.safe_load(client.get(f"/api/runs/{rid}/files/location_recorder.yaml").text)
    assert list(doc) == list(anchors)
    for entry in doc.values():
        assert set(entry) == {"position", "orientation"}
        assert set(entry["position"]) == {"x", "y", "z"}
        assert set(entry["orientation"]) == {"x", "y", "z", "w"}
    assert client.post(f"/api/runs/{rid}/cancel").status_code == 202
    final = wait_status(client, rid, FINAL)
    assert final["status"] == "aborted"
    assert set(final["result"]["rooms_recorded"]) == set(anchors)
    assert client.post(f"/api/runs/{rid}/rooms/kitchen").status_code == 409


async def _seed_003(
    server: Server, rid: str, anchors: dict[str, tuple[float, float]]
) -> dict[str, dict]:
    """Drive by cmd_vel a little, then per room: a goal, wait for arrival, record."""
    replies: dict[str, dict] = {}
    async with (
        httpx.AsyncClient(base_url=server.url, timeout=30.0) as http,
        websockets.connect(f"{server.ws_url}/api/runs/{rid}/live", max_size=1 << 24) as ws,
    ):
        events: list[dict] = []
        states: list[dict] = []
        arrived = asyncio.Event()

        async def read() -> None:
            async for text in ws:
                m = json.loads(text)
                if m["type"] == "state":
                    states.append(m)
                elif m["type"] == "event":
                    events.append(m)
                    if m["event"] in ("goal_reached", "goal_failed"):
                        arrived.set()

        reader = asyncio.create_task(read())
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 60.0  # "running" comes before the worker's first step
        while not any(m["v"] > 0.05 for m in states):  # until it drives under remote command
            assert loop.time() < deadline, f"no state under cmd_vel: {states[-1:]}"
            await ws.send(json.dumps({"type": "cmd_vel", "v": 0.15, "w": 0.0}))
            await asyncio.sleep(0.1)
        assert states[-1]["task"] == {"index": 0, "type": "teleop"}
        for label, (x, y) in anchors.items():
            arrived.clear()
            response = await http.post(f"/api/runs/{rid}/goal", json={"x": x, "y": y, "yaw": 0.0})
            assert response.status_code == 202
            await asyncio.wait_for(arrived.wait(), 120)
            assert events[-1]["event"] == "goal_reached", events[-1]
            recorded = await http.post(f"/api/runs/{rid}/rooms/{label}")
            assert recorded.status_code == 200, recorded.text
            replies[label] = recorded.json()
        reader.cancel()
    return replies
