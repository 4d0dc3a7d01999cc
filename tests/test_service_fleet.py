"""Fleets through the service: a real server process on a loopback port, real HTTP and
WebSocket clients. Every robot's messages name it; commands name their robot (or may leave
it out when the run has one)."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
from pathlib import Path

import httpx
import pytest
import websockets
import yaml

from agv_mission.missions.report.palette import ROBOT_COLOURS
from agv_mission.service.models import StreamRobots
from service_server import (
    AGV,
    FINAL,
    SHORT_FLEET,
    SHORT_MISSION,
    TELEOP_FLEET,
    Server,
    collect_live,
    submit,
    wait_status,
)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    with Server(tmp_path_factory.mktemp("svc-fleet") / "data", "--workers", "2") as srv:
        yield srv


@pytest.fixture
def client(server: Server):
    with server.client() as c:
        yield c


def _hex(name: str) -> str:
    from matplotlib.colors import to_hex

    return to_hex(name)


def test_fleet_stream_names_every_robot(server: Server, client: httpx.Client) -> None:
    run = submit(client, SHORT_FLEET)
    messages = asyncio.run(collect_live(f"{server.ws_url}/api/runs/{run['id']}/live"))
    assert messages[-1]["type"] == "end" and messages[-1]["status"] == "succeeded"
    robots = [m for m in messages if m["type"] == "robots"]
    assert len(robots) == 1
    start = StreamRobots.model_validate(robots[0])  # the typed message, as documented
    assert start.fleet and [r.name for r in start.robots] == ["agv1", "agv2"]
    assert [r.type for r in start.robots] == ["burger", "waffle"]
    assert [r.colour for r in start.robots] == [_hex(c) for c in ROBOT_COLOURS[:2]]
    assert start.robots[1].start.x == pytest.approx(2.0) and start.robots[1].radius > 0.15
    # agv2 holds two legs, agv1 one: their trees differ
    assert len(start.robots[1].tree) > len(start.robots[0].tree) >= 2

    def of(kind: str, robot: str) -> list[dict]:
        return [m for m in messages if m["type"] == kind and m.get("robot") == robot]

    for name, goal in (("agv1", (-2.0, 1.0)), ("agv2", (1.8, -1.0))):
        states = of("state", name)
        assert len(states) >= 5, name
        assert math.dist((states[-1]["pose"]["x"], states[-1]["pose"]["y"]), goal) < 0.3
        assert of("plan", name) and of("tree", name)
        reached = [e for e in of("event", name) if e["event"] == "goal_reached"]
        assert len(reached) == (1 if name == "agv1" else 2)
    # each robot's states span the run (one robot's never crowd out the other's)
    end_t = max(m["t"] for m in messages if m["type"] == "state")
    for name in ("agv1", "agv2"):
        ts = [m["t"] for m in of("state", name)]
        assert ts[0] <= 0.5 and ts[-1] == end_t

    final = wait_status(client, run["id"], FINAL)
    assert set(final["progress"]["robots"]) == {"agv1", "agv2"}
    assert set(final["result"]["robots"]) == {"agv1", "agv2"}

    # a late client: the snapshot holds every robot's latest tree and state
    late = asyncio.run(collect_live(f"{server.ws_url}/api/runs/{run['id']}/live"))
    snap = {(m["type"], m.get("robot")) for m in late}
    for name in ("agv1", "agv2"):
        assert {("state", name), ("tree", name), ("plan", name)} <= snap
    assert ("robots", None) in snap and late[-1]["type"] == "end"

    schema = client.get("/openapi.json").json()
    assert "StreamRobots" in schema["components"]["schemas"]
    goal_params = schema["paths"]["/api/runs/{run_id}/goal"]["post"]["parameters"]
    assert any(p["name"] == "robot" and p["in"] == "query" for p in goal_params)


def test_one_robot_stream_names_its_robot(server: Server, client: httpx.Client) -> None:
    run = submit(client, SHORT_MISSION)
    messages = asyncio.run(collect_live(f"{server.ws_url}/api/runs/{run['id']}/live"))
    (robots,) = [m for m in messages if m["type"] == "robots"]
    assert robots["fleet"] is False and [r["name"] for r in robots["robots"]] == ["robot"]
    states = [m for m in messages if m["type"] == "state"]
    assert states and {m["robot"] for m in states} == {"robot"}


def test_fleet_teleop_commands_name_their_robot(server: Server, client: httpx.Client) -> None:
    run = submit(client, TELEOP_FLEET)
    rid = run["id"]
    wait_status(client, rid, {"running"})
    try:
        asyncio.run(_drive_each(server, rid))
    finally:
        client.post(f"/api/runs/{rid}/cancel")
    final = wait_status(client, rid, FINAL)
    assert final["status"] == "aborted"
    recorder = yaml.safe_load(client.get(f"/api/runs/{rid}/files/location_recorder.yaml").text)
    assert list(recorder) == ["spot"]
    assert recorder["spot"]["position"]["x"] == pytest.approx(1.8, abs=0.3)


async def _drive_each(server: Server, rid: str) -> None:
    async with (
        httpx.AsyncClient(base_url=server.url, timeout=30.0) as http,
        websockets.connect(f"{server.ws_url}/api/runs/{rid}/live", max_size=1 << 24) as ws,
    ):
        states: dict[str, list[dict]] = {"agv1": [], "agv2": []}
        events: list[dict] = []
        frames: list[dict] = []
        reached = asyncio.Event()

        async def read() -> None:
            async for text in ws:
                m = json.loads(text)
                if m["type"] == "state":
                    states[m["robot"]].append(m)
                elif m["type"] == "event":
                    events.append(m)
                    if m["event"] == "goal_reached":
                        reached.set()
                elif m["type"] in ("error", "clamped"):
                    frames.append(m)

        reader = asyncio.create_task(read())
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 60.0
        while not (states["agv1"] and states["agv2"]):
            assert loop.time() < deadline, "no state of both robots"
            await asyncio.sleep(0.05)
        # the robot is named, or refused: a fleet run does not guess
        await ws.send(json.dumps({"type": "cmd_vel", "v": 0.1, "w": 0.0}))
        await ws.send(json.dumps({"type": "cmd_vel", "v": 0.1, "w": 0.0, "robot": "agv9"}))
        while len(frames) < 2:
            assert loop.time() < deadline, f"no error frames: {frames}"
            await asyncio.sleep(0.05)
        assert frames[0]["type"] == "error" and "agv1, agv2" in frames[0]["message"]
        assert frames[1]["type"] == "error" and "agv9" in frames[1]["message"]
        for query, word in (("", "agv1, agv2"), ("?robot=agv9", "agv9")):
            refused = await http.post(f"/api/runs/{rid}/goal{query}", json={"x": 0.0, "y": 0.0})
            assert refused.status_code == 422 and word in refused.text, refused.text
        refused = await http.post(f"/api/runs/{rid}/rooms/spot")
        assert refused.status_code == 422 and "agv1, agv2" in refused.text

        # agv1 alone drives under remote command
        x0 = states["agv2"][-1]["pose"]["x"]
        while not any(m["v"] > 0.05 for m in states["agv1"]):
            assert loop.time() < deadline, f"agv1 does not drive: {states['agv1'][-1:]}"
            await ws.send(json.dumps({"type": "cmd_vel", "v": 0.15, "w": 0.0, "robot": "agv1"}))
            await asyncio.sleep(0.1)
        assert all(abs(m["v"]) < 1e-3 for m in states["agv2"])
        assert states["agv1"][-1]["task"] == {"index": 0, "type": "teleop"}

        # a goal to agv2 reaches agv2; agv1 stays where it stopped
        await asyncio.sleep(0.8)  # agv1's last command goes stale (0.5 s): it stops
        a1 = states["agv1"][-1]["pose"]
        sent = await http.post(f"/api/runs/{rid}/goal?robot=agv2", json={"x": 1.8, "y": -1.0})
        assert sent.status_code == 202 and sent.json()["robot"] == "agv2", sent.text
        await asyncio.wait_for(reached.wait(), 120)
        assert [e["robot"] for e in events if e["event"] == "goal_reached"] == ["agv2"]
        await asyncio.sleep(0.3)
        p2 = states["agv2"][-1]["pose"]
        assert math.dist((p2["x"], p2["y"]), (1.8, -1.0)) < 0.3 and abs(p2["x"] - x0) > 0.1
        p1 = states["agv1"][-1]["pose"]
        assert math.dist((p1["x"], p1["y"]), (a1["x"], a1["y"])) < 0.05

        recorded = await http.post(f"/api/runs/{rid}/rooms/spot?robot=agv2")
        assert recorded.status_code == 200, recorded.text
        body = recorded.json()
        assert (
            body["robot"] == "agv2"
            and math.dist((body["pose"]["x"], body["pose"]["y"]), (1.8, -1.0)) < 0.3
        )
        reader.cancel()


def test_submit_follow_prints_the_fleet_summary(server: Server, tmp_path: Path) -> None:
    mission = tmp_path / "pair.yaml"
    mission.write_text(SHORT_FLEET)
    done = subprocess.run(
        [AGV, "submit", str(mission), "--server", server.url, "--follow"],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr
    assert "2 robots in turtlebot3_world: agv1 (burger), agv2 (waffle)" in done.stdout
    assert "succeeded" in done.stdout and "agv2: 2. go_to" in done.stdout
