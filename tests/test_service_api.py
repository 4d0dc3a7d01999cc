"""The service as a new user meets it: an OpenAPI document a client can be generated from,
their own map, rooms and robot files travelling with a mission (``submit`` and raw HTTP),
bags of service runs, and the edges of teleop (goals, WebSocket frames, clamped commands)
and of ``submit`` (exit codes, what ``--follow`` prints). A real server process, real
HTTP/WebSocket clients, the real bag reader."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
import websockets
import yaml
from openapi_spec_validator import validate as validate_openapi
from PIL import Image
from rosbags.highlevel import AnyReader

from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from cli_in_process import agv
from service_server import AGV, FINAL, SHORT_MISSION, Server, submit, wait_status


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    with Server(tmp_path_factory.mktemp("svc-api") / "data", "--workers", "2") as srv:
        yield srv


@pytest.fixture
def client(server: Server):
    with server.client() as c:
        yield c


# --------------------------------------------------------------------------- OpenAPI


def test_openapi_document_is_valid_3_1_and_types_every_body_and_answer(
    client: httpx.Client,
) -> None:
    doc = client.get("/openapi.json").json()
    validate_openapi(doc)  # raises on anything OpenAPI 3.1 does not allow
    assert doc["openapi"].startswith("3.1")
    assert client.get("/api/openapi.json").json() == doc
    schemas = doc["components"]["schemas"]
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            for status, answer in op["responses"].items():
                content = answer.get("content")
                assert content, (method, path, status)
                for media in content.values():
                    schema = media["schema"]
                    assert schema.get("$ref") or schema.get("type") == "string", (
                        method,
                        path,
                        status,
                        schema,
                    )
                    if "$ref" in schema:
                        assert schema["$ref"].rsplit("/", 1)[-1] in schemas
            if method == "post" and path in (
                "/api/runs",
                "/api/validate",
                "/api/runs/{run_id}/goal",
            ):
                body = op["requestBody"]["content"]
                assert body["application/json"]["schema"]["$ref"].endswith(("/Submit", "/Goal"))
    submit_body = doc["paths"]["/api/runs"]["post"]["requestBody"]["content"]
    assert set(submit_body) == {"application/json", "application/yaml"}
    upload = doc["paths"]["/api/runs/upload"]["post"]["requestBody"]["content"]
    assert upload["multipart/form-data"]["schema"]["$ref"].endswith("/SubmitWithFiles")
    assert set(schemas["Run"]["properties"]) >= {
        "id", "name", "status", "reason", "created", "started", "ended", "progress", "result"
    }  # fmt: skip
    assert "HTTPValidationError" not in schemas  # every 422 is the contract's problem list


def test_docs_page_uses_only_the_package_assets(client: httpx.Client) -> None:
    page = client.get("/docs")
    assert page.status_code == 200
    assets = [a for a in ("/docs-assets/swagger-ui-bundle.js", "/docs-assets/swagger-ui.css")]
    for asset in assets:
        assert asset in page.text
        assert client.get(asset).status_code == 200
    assert "cdn" not in page.text.lower() and "https://" not in page.text


def test_malformed_query_answers_the_problem_list(client: httpx.Client) -> None:
    for params in ({"limit": "many"}, {"limit": 0}, {"status": "sleeping"}):
        response = client.get("/api/runs", params=params)
        assert response.status_code == 422, params
        problem = response.json()["errors"][0]
        assert problem["field"] in ("limit", "status") and problem["message"]


def test_hostile_submissions_answer_422_and_leave_the_service_up(client: httpx.Client) -> None:
    """A body nested past the JSON parser's depth, a seed past 63 bits (the registry's
    integers), a pace whose waits overflow the clock: each a 422 naming the field, none a
    500 or a run that dies of it; the service answers on."""
    mission = (Path(__file__).parents[1] / "missions" / "patrol.yaml").read_text()
    cases = [
        ("[" * 100_000 + "]" * 100_000, ""),
        (json.dumps({"mission": mission, "seed": 2**200}), "seed"),
        (json.dumps({"mission": mission, "pace": 1e-300}), "pace"),
        (json.dumps({"mission": mission, "pace": 1e308}), "pace"),
    ]
    for body, field in cases:
        answer = client.post(
            "/api/runs", content=body.encode(), headers={"Content-Type": "application/json"}
        )
        assert answer.status_code == 422, (field, answer.text[:200])
        assert answer.json()["errors"][0]["field"] == field
    assert client.get("/api/health").json()["status"] == "ok"


# --------------------------------------------------------------------------- own files


def own_map_mission(folder: Path) -> Path:
    """A user's own map_server map (5 x 4 m lab with a sealed closet), rooms file and robot
    file, beside a mission in a folder of its own that names them by relative paths."""
    res = 0.05
    pixels = np.full((80, 100), 254, np.uint8)  # top row first, as map_saver writes
    pixels[:3, :] = pixels[-3:, :] = pixels[:, :3] = pixels[:, -3:] = 0
    pixels[5:25, 75:95] = 0  # the closet: walls all round a free inside
    pixels[8:22, 78:92] = 254
    (folder / "maps").mkdir(parents=True)
    Image.fromarray(pixels).save(folder / "maps" / "lab.pgm")
    (folder / "maps" / "lab.yaml").write_text(
        "image: lab.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    assert pixels.shape[1] * res == 5.0
    (folder / "rooms").mkdir()
    (folder / "rooms" / "lab_rooms.yaml").write_text(
        "rooms:\n"
        "  bench:\n    polygon: [[0.3, 0.3], [2.2, 0.3], [2.2, 2.6], [0.3, 2.6]]\n"
        "  door:\n    polygon: [[2.8, 0.3], [4.6, 0.3], [4.6, 2.6], [2.8, 2.6]]\n"
        "    anchor: {x: 3.5, y: 1.2, yaw: 0.0}\n"
    )
    (folder / "robots").mkdir()
    robot = BUILTIN_ROBOTS["burger"].model_dump(mode="json")
    robot["name"] = "lab_bot"
    (folder / "robots" / "lab_bot.yaml").write_text(yaml.safe_dump(robot))
    (folder / "records").mkdir()
    (folder / "records" / "location_recorder.yaml").write_text(
        "bench:\n  position: {x: 1.0, y: 1.2, z: 0.0}\n"
        "  orientation: {x: 0.0, y: 0.0, z: 0.0, w: 1.0}\n"
    )
    (folder / "missions").mkdir()
    mission = folder / "missions" / "lab.yaml"
    mission.write_text(
        "name: lab\n"
        "world: ../maps/lab.yaml\n"
        "rooms: ../rooms/lab_rooms.yaml\n"
        "robot: ../robots/lab_bot.yaml\n"
        "recorder: ../records/location_recorder.yaml\n"
        "start: {x: 1.0, y: 1.2, yaw: 0.0}\n"
        "stack: {localization: {type: ground_truth}, global_planner: {type: grid_astar}}\n"
        "tasks:\n  - {type: visit_rooms, rooms: [door], record: true}\n"
        "limits: {time: 40}\n"
    )
    return mission


def bag_topics(bag: Path) -> set[str]:
    with AnyReader([bag]) as reader:
        return {c.topic for c in reader.connections if c.msgcount > 0}


def test_submit_sends_the_files_the_mission_names(server: Server, tmp_path: Path) -> None:
    mission = own_map_mission(tmp_path / "user")
    done = subprocess.run(
        [AGV, "submit", str(mission), "--server", server.url, "--follow"],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    run_id = lines[0].strip()
    # what `run` prints: the mission line, the status, the task table, metrics, directory
    assert lines[1].startswith("lab: 1 task(s) in ") and "with lab_bot, seed" in lines[1]
    assert lines[2] == "succeeded"
    assert "visit_rooms" in done.stdout and "run directory:" in done.stdout
    assert "{'" not in done.stdout + done.stderr  # no Python dict reprs
    run_dir = server.data / "runs" / run_id
    inputs = {p.relative_to(run_dir / "inputs").as_posix() for p in run_dir.glob("inputs/**/*")}
    assert {
        "missions/lab.yaml",
        "maps/lab.yaml",
        "maps/lab.pgm",
        "rooms/lab_rooms.yaml",
        "robots/lab_bot.yaml",
        "records/location_recorder.yaml",
    } <= inputs
    # the run recorded into the copy that travelled, keeping the user's own entry
    recorded = yaml.safe_load((run_dir / "inputs/records/location_recorder.yaml").read_text())
    assert list(recorded) == ["bench", "door"]
    result = json.loads((run_dir / "result.json").read_text())
    assert result["robot"] == "lab_bot" and result["status"] == "succeeded"
    assert {"/scan", "/odom", "/tf", "/events", "/map", "/rooms"} <= bag_topics(run_dir / "bag")


def test_raw_http_multipart_takes_a_mission_with_its_files(
    server: Server, client: httpx.Client, tmp_path: Path
) -> None:
    user = tmp_path / "user"
    mission = own_map_mission(user)
    names = [
        "maps/lab.yaml",
        "maps/lab.pgm",
        "rooms/lab_rooms.yaml",
        "robots/lab_bot.yaml",
        "records/location_recorder.yaml",
    ]
    # curl as a user would type it: the mission as a file part, each file named by its path
    curl = subprocess.run(
        [
            "curl", "-sS", "-o", "-", "-w", "\n%{http_code}",
            "-F", f"mission=@{mission}",
            "-F", "mission_path=missions/lab.yaml",
            "-F", "seed=4",
            *[a for n in names for a in ("-F", f"files=@{user / n};filename={n}")],
            server.url + "/api/runs",
        ],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    body, code = curl.stdout.rsplit("\n", 1)
    assert code == "201", body
    run = json.loads(body)
    assert run["name"] == "lab" and run["seed"] == 4
    final = wait_status(client, run["id"], FINAL)
    assert final["status"] == "succeeded", final["reason"]
    assert final["result"]["robot"] == "lab_bot" and final["result"]["seed"] == 4
    run_dir = server.data / "runs" / run["id"]
    assert (run_dir / "inputs" / "maps" / "lab.pgm").read_bytes() == (
        user / "maps" / "lab.pgm"
    ).read_bytes()
    assert "/scan" in bag_topics(run_dir / "bag")


def test_uploaded_files_are_confined(server: Server, client: httpx.Client, tmp_path: Path) -> None:
    user = tmp_path / "user"
    own_map_mission(user)
    good = {n: (user / n).read_bytes() for n in ("maps/lab.yaml", "maps/lab.pgm")}
    flat = (  # the map alone travels: built-in robot, no rooms, no recorder
        "name: lab\nworld: ../maps/lab.yaml\nstart: {x: 1.0, y: 1.2, yaw: 0.0}\n"
        "tasks:\n  - {type: go_to, pose: {x: 3.5, y: 1.2, yaw: 0}}\n"
    )
    before = set((server.data / "runs").iterdir())

    def post(files: dict[str, bytes], mission_text: str = flat, **data: str) -> httpx.Response:
        parts = [("files", (name, content)) for name, content in files.items()]
        return client.post(
            "/api/runs",
            data={"mission": mission_text, "mission_path": "missions/lab.yaml", **data},
            files=parts,
        )

    for bad_name in ("../escape.yaml", "/etc/evil.yaml", "maps/.hidden", "a\\b.yaml", "./x"):
        response = post({**good, bad_name: b"rooms: {}\n"})
        assert response.status_code == 422, (bad_name, response.text)
        assert response.json()["errors"][0]["field"] == "files"
    unnamed = post({**good, "maps/extra.txt": b"not named by the mission"})
    assert unnamed.status_code == 422 and "names no such file" in unnamed.json()["detail"]
    escaping = post(good, mission_path="../../m.yaml")
    assert escaping.status_code == 422 and escaping.json()["errors"][0]["field"] == "mission_path"
    too_many = post({f"f{i}.yaml": b"" for i in range(40)})
    assert too_many.status_code == 422
    missing = post({"maps/lab.yaml": good["maps/lab.yaml"]})  # the image did not come along
    assert missing.status_code == 422 and missing.json()["errors"][0]["field"] == "world"

    def huge():
        yield b'--x\r\nContent-Disposition: form-data; name="files"; filename="a.pgm"\r\n\r\n'
        for _ in range(70):
            yield b"#" * 1_000_000
        yield b"\r\n--x--\r\n"

    too_big = client.post(
        "/api/runs", content=huge(), headers={"Content-Type": "multipart/form-data; boundary=x"}
    )
    assert too_big.status_code == 413
    assert set((server.data / "runs").iterdir()) == before  # nothing refused stays behind


def test_output_dir_is_refused_and_output_bag_honoured(
    server: Server, client: httpx.Client
) -> None:
    elsewhere = SHORT_MISSION + "output: /tmp/elsewhere\n"
    refused = client.post("/api/runs", json={"mission": elsewhere})
    assert refused.status_code == 422
    problem = refused.json()["errors"][0]
    assert problem["field"] == "output" and problem["line"] == len(SHORT_MISSION.splitlines()) + 1
    assert "DATA/runs/<run id>" in problem["message"]
    via_set = client.post("/api/runs", json={"mission": SHORT_MISSION, "set": ["output=out"]})
    assert via_set.status_code == 422 and via_set.json()["errors"][0]["field"] == "output"
    assert (
        client.post("/api/validate", json={"mission": SHORT_MISSION + "output: runs\n"}).status_code
        == 200
    )
    run = submit(client, SHORT_MISSION + "output: {bag: false}\n")
    assert wait_status(client, run["id"], FINAL)["status"] == "succeeded"
    assert not (server.data / "runs" / run["id"] / "bag").exists()


# --------------------------------------------------------------------------- teleop edges

TELEOP = (
    "name: teleop\nworld: turtlebot3_world\nstart: {x: -2.0, y: -0.5, yaw: 0.0}\n"
    "stack: {localization: {type: ground_truth}, global_planner: {type: grid_astar}}\n"
    "tasks:\n  - {type: teleop}\n"
)


def test_teleop_edges(server: Server, client: httpx.Client) -> None:
    run = submit(client, TELEOP)
    rid = run["id"]
    wait_status(client, rid, {"running"})
    try:
        answers = asyncio.run(_teleop_session(server, client, rid))
    finally:
        client.post(f"/api/runs/{rid}/cancel")
    assert answers["not json"]["type"] == "error" and "JSON" in answers["not json"]["message"]
    assert answers["unknown"]["type"] == "error" and "warp" in answers["unknown"]["message"]
    assert answers["bad v"]["type"] == "error" and "v" in answers["bad v"]["message"]
    clamped = answers["too fast"]
    assert clamped["type"] == "clamped"
    burger = BUILTIN_ROBOTS["burger"]
    assert clamped["v"] == burger.max_linear_velocity
    assert clamped["w"] == -burger.max_angular_velocity
    assert clamped["requested"] == {"v": 5.0, "w": -9}
    assert answers["pong"]["type"] == "pong"
    wall = answers["goal"]
    # a goal drive runs at wall speed: simulated time never outruns the wall clock (load
    # only slows the simulation, so this bound cannot fail under load; unpaced it ran ~90x)
    assert wall["sim"] <= 2.0 * wall["wall"] + 1.0, wall
    assert wall["events"][-1] == "goal_reached"
    final = wait_status(client, rid, FINAL)
    assert final["status"] == "aborted"


async def _teleop_session(server: Server, client: httpx.Client, rid: str) -> dict:
    answers: dict = {}
    async with (
        httpx.AsyncClient(base_url=server.url, timeout=30.0) as http,
        websockets.connect(f"{server.ws_url}/api/runs/{rid}/live", max_size=1 << 24) as ws,
    ):
        inbox: asyncio.Queue = asyncio.Queue()
        states: list[dict] = []
        events: list[str] = []

        async def read() -> None:
            async for text in ws:
                m = json.loads(text)
                if m["type"] == "state":
                    states.append(m)
                elif m["type"] == "event":
                    events.append(m["event"])
                elif m["type"] in ("error", "clamped", "pong"):
                    await inbox.put(m)

        reader = asyncio.create_task(read())

        async def ask(frame: str) -> dict:
            await ws.send(frame)
            return await asyncio.wait_for(inbox.get(), 30)

        loop = asyncio.get_running_loop()
        deadline = loop.time() + 60.0
        while not states or states[-1]["task"] != {"index": 0, "type": "teleop"}:
            assert loop.time() < deadline, "the teleop task did not start"
            await asyncio.sleep(0.05)
        answers["not json"] = await ask("{not json")
        answers["unknown"] = await ask(json.dumps({"type": "warp", "x": 3}))
        answers["bad v"] = await ask(json.dumps({"type": "cmd_vel", "v": "fast", "w": 0}))
        answers["too fast"] = await ask(json.dumps({"type": "cmd_vel", "v": 5.0, "w": -9}))
        answers["pong"] = await ask(json.dumps({"type": "ping"}))

        for x, y, why in ((0.0, 0.0, "obstacle"), (40.0, 0.0, "outside the map")):
            refused = await http.post(f"/api/runs/{rid}/goal", json={"x": x, "y": y})
            assert refused.status_code == 422, refused.text
            assert why in refused.json()["detail"]
        for body, field in (({"x": 1.0}, "y"), ({"x": 1, "y": 0, "z": 0}, "z")):
            malformed = await http.post(f"/api/runs/{rid}/goal", json=body)
            assert malformed.status_code == 422 and malformed.json()["errors"][0]["field"] == field
        await asyncio.sleep(1.0)  # the clamped command goes stale: the robot stops
        sim0, wall0 = states[-1]["t"], time.monotonic()
        goal = await http.post(f"/api/runs/{rid}/goal", json={"x": -1.4, "y": -0.5})
        assert goal.status_code == 202, goal.text
        deadline = loop.time() + 120.0
        while not {"goal_reached", "goal_failed"} & set(events):
            assert loop.time() < deadline, "the goal drive did not end"
            await asyncio.sleep(0.05)
        answers["goal"] = {
            "sim": states[-1]["t"] - sim0,
            "wall": time.monotonic() - wall0,
            "events": [e for e in events if e.startswith("goal_")],
        }
        reader.cancel()
    return answers


# --------------------------------------------------------------------------- submit exits


def test_submit_to_an_unreachable_server_exits_69(tmp_path: Path) -> None:
    mission = tmp_path / "short.yaml"
    mission.write_text(SHORT_MISSION)
    gone = agv("submit", str(mission), "--server", "http://127.0.0.1:9")  # in this process
    assert gone.returncode == 69, gone.stderr
    assert "cannot reach" in gone.stderr and "Traceback" not in gone.stderr
    bad = tmp_path / "bad.yaml"
    bad.write_text(SHORT_MISSION.replace("x: -1.5", "x: fast"))
    invalid = agv("submit", str(bad), "--server", "http://127.0.0.1:9")
    assert invalid.returncode == 2  # invalid input is found before anything is sent
    assert f"{bad}:6" in invalid.stderr


# --------------------------------------------------------------------------- a generated client


@pytest.mark.slow
def test_a_generated_client_submits_and_follows_runs(
    server: Server, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``openapi-python-client`` (a dev dependency) generates a client from /openapi.json;
    it submits a mission as JSON and one with its files as multipart, and follows both."""
    bin_dir = Path(sys.executable).parent
    (tmp_path / "openapi.json").write_text(httpx.get(server.url + "/openapi.json").text)
    subprocess.run(
        [bin_dir / "openapi-python-client", "generate", "--path", "openapi.json",
         "--meta", "none", "--output-path", "agv_generated"],
        cwd=tmp_path, check=True, capture_output=True, timeout=300,
        env={**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"},
    )  # fmt: skip
    monkeypatch.syspath_prepend(str(tmp_path))
    from agv_generated import Client
    from agv_generated.api.runs import one_run, submit, submit_with_files
    from agv_generated.models import Problems, Run, Submit, SubmitWithFiles
    from agv_generated.types import File

    api = Client(base_url=server.url, raise_on_unexpected_status=True)

    def follow(run_id: str) -> Run:
        deadline = time.monotonic() + 180
        while True:
            run = one_run.sync(run_id, client=api)
            assert isinstance(run, Run)
            if run.status.value in FINAL:
                return run
            assert time.monotonic() < deadline, run.status
            time.sleep(0.1)

    queued = submit.sync(client=api, body=Submit(mission=SHORT_MISSION, seed=5))
    assert isinstance(queued, Run) and queued.status.value == "queued"
    done = follow(queued.id)
    assert done.status.value == "succeeded" and done.result["seed"] == 5

    user = tmp_path / "user"
    own_map_mission(user)
    names = [
        "maps/lab.yaml",
        "maps/lab.pgm",
        "rooms/lab_rooms.yaml",
        "robots/lab_bot.yaml",
        "records/location_recorder.yaml",
    ]
    body = SubmitWithFiles(
        mission=(user / "missions" / "lab.yaml").read_text(),
        mission_path="missions/lab.yaml",
        files=[File(payload=(user / n).open("rb"), file_name=n) for n in names],
    )
    with_files = submit_with_files.sync(client=api, body=body)
    assert isinstance(with_files, Run), with_files
    done = follow(with_files.id)
    assert done.status.value == "succeeded" and done.result["robot"] == "lab_bot"

    refused = submit.sync(client=api, body=Submit(mission="tasks: 3\n"))
    assert isinstance(refused, Problems) and refused.errors[0].field
    sys.modules.pop("agv_generated", None)


def test_goal_into_a_sealed_room_of_an_own_map_answers_422(
    server: Server, client: httpx.Client, tmp_path: Path
) -> None:
    user = tmp_path / "user"
    own_map_mission(user)
    teleop = (
        "name: lab-teleop\nworld: lab.yaml\nstart: {x: 1.0, y: 1.2, yaw: 0.0}\n"
        "stack: {localization: {type: ground_truth}, global_planner: {type: grid_astar}}\n"
        "tasks:\n  - {type: teleop, duration: 300}\n"
    )
    parts = [("files", (n, (user / "maps" / n).read_bytes())) for n in ("lab.yaml", "lab.pgm")]
    response = client.post("/api/runs/upload", data={"mission": teleop}, files=parts)
    assert response.status_code == 201, response.text
    rid = response.json()["id"]
    try:
        run = wait_status(client, rid, {"running"})
        deadline = time.monotonic() + 60
        while run["progress"]["task_type"] != "teleop":
            assert time.monotonic() < deadline, run["progress"]
            time.sleep(0.05)
            run = client.get(f"/api/runs/{rid}").json()
        closet = client.post(f"/api/runs/{rid}/goal", json={"x": 4.25, "y": 3.25})
        assert closet.status_code == 422, closet.text
        assert "no free corridor" in closet.json()["detail"]
        open_floor = client.post(f"/api/runs/{rid}/goal", json={"x": 2.0, "y": 1.2})
        assert open_floor.status_code == 202, open_floor.text
    finally:
        client.post(f"/api/runs/{rid}/cancel")
    assert wait_status(client, rid, FINAL)["status"] == "aborted"
