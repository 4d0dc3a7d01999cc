"""Watchable runs (issue 34): a pace of simulated seconds per wall second for ``run``,
``submit`` and the service, changeable while a run runs; pacing never changes a result.
And the dashboard's 404 answers, and tree missions summarised by their tree."""

from __future__ import annotations

import asyncio
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.pacing import PacedControl, Pacer, check_pace
from agv_mission.missions.run.runner import run_mission
from cli_in_process import agv
from mission_texts import ENDLESS_PATROL, mission_file, tb3_mission
from service_server import AGV, SHORT_MISSION, Server, collect_live, submit, wait_status

LONG = tb3_mission(
    ENDLESS_PATROL,
    limits="{time: 600}",
    stack="{localization: {type: ground_truth}, global_planner: {type: grid_astar}}",
    name="long",
    robot=None,
)


def test_pacing_changes_no_result(tmp_path: Path) -> None:
    """The same seed paced and flat out: the same trajectory, sample for sample; the paced
    run did wait between its steps."""
    path = mission_file(tmp_path, SHORT_MISSION)
    flat = run_mission(load_mission(path))
    waits: list[float] = []

    def sleep(seconds: float) -> None:
        waits.append(seconds)
        time.sleep(seconds)

    paced = run_mission(load_mission(path), control=PacedControl(None, 1.0, sleep))
    assert flat.status == paced.status == "succeeded"
    assert waits and all(w > 0 for w in waits)
    np.testing.assert_array_equal(flat.trajectory, paced.trajectory)
    assert flat.events == paced.events


def test_a_pace_is_a_positive_number() -> None:
    assert check_pace(None) is None and check_pace(2) == 2.0
    # beyond a million times real time, or under a thousandth, a wait overflows the clock
    for bad in (0, -1.0, float("nan"), float("inf"), True, "1", 1e-300, 1e308):
        with pytest.raises(ValueError):
            check_pace(bad)  # type: ignore[arg-type]
    pacer = Pacer(4.0)
    assert pacer.delay(0.0) == 0.0  # the first step anchors the pace
    assert pacer.delay(100.0) == 0.0  # a jump (a pause, a slow stretch) re-anchors
    pacer.set(None)
    assert pacer.delay(200.0) == 0.0


def test_run_at_a_pace_prints_its_speed(tmp_path: Path) -> None:
    path = mission_file(tmp_path, SHORT_MISSION)
    proc = subprocess.run(
        [AGV, "run", str(path), "--pace", "4", "--output", str(tmp_path / "runs"), "--no-bag"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "succeeded" in proc.stdout
    bad = agv("run", str(path), "--pace", "0")  # typer's own check, called in this process
    assert bad.returncode == 2 and "--pace" in bad.stderr


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    with Server(tmp_path_factory.mktemp("pace-serve"), "--workers", "2") as server:
        yield server


def test_a_paced_run_can_be_watched_paused_resumed_and_repaced(service: Server) -> None:
    with service.client() as client:
        run = submit(client, LONG, pace=1.0)
        assert run["pace"] == 1.0
        run_id = run["id"]
        wait_status(client, run_id, {"running"})
        time.sleep(5.0)  # the hidden check's wait: at pace 1 it is still running
        assert client.get(f"/api/runs/{run_id}").json()["status"] == "running"
        assert client.post(f"/api/runs/{run_id}/pause").status_code == 202
        held = wait_status(client, run_id, {"paused"})["progress"]["sim_time"]
        assert client.post(f"/api/runs/{run_id}/resume").status_code == 202
        wait_status(client, run_id, {"running"})
        answer = client.post(f"/api/runs/{run_id}/pace", json={"pace": 4.0})
        assert answer.status_code == 202 and answer.json() == {"id": run_id, "pace": 4.0}
        assert client.get(f"/api/runs/{run_id}").json()["pace"] == 4.0
        deadline = time.monotonic() + 120
        while client.get(f"/api/runs/{run_id}").json()["progress"]["sim_time"] <= held:
            assert time.monotonic() < deadline, "the run did not go on after resume"
            time.sleep(0.2)
        # a client that connects late gets the events so far after the snapshot
        while client.get(f"/api/runs/{run_id}").json()["progress"]["sim_time"] < 6.0:
            assert time.monotonic() < deadline, "the patrol did not get on"
            time.sleep(0.2)
        late = asyncio.run(collect_live(f"{service.ws_url}/api/runs/{run_id}/live", limit=60))
        first_state = next(m for m in late if m["type"] == "state")
        past = [m for m in late if m["type"] == "event" and m["t"] <= first_state["t"]]
        assert any(m["event"] == "goal_reached" for m in past), [m["type"] for m in late]
        for bad in ({"pace": 0}, {"pace": "fast"}, {"speed": 2}):
            assert client.post(f"/api/runs/{run_id}/pace", json=bad).status_code == 422
        flat = client.post(f"/api/runs/{run_id}/pace", json={"pace": None})
        assert flat.status_code == 202 and client.get(f"/api/runs/{run_id}").json()["pace"] is None
        assert client.post(f"/api/runs/{run_id}/cancel").status_code == 202
        wait_status(client, run_id, {"aborted"})
        assert client.post(f"/api/runs/{run_id}/pace", json={"pace": 2.0}).status_code == 409
        assert client.post("/api/runs/nope/pace", json={"pace": 2.0}).status_code == 404
        bad = client.post("/api/runs", json={"mission": SHORT_MISSION, "pace": -1})
        assert bad.status_code == 422 and bad.json()["errors"][0]["field"] == "pace"


def test_submit_takes_a_pace(service: Server, tmp_path: Path) -> None:
    path = mission_file(tmp_path, LONG)
    proc = subprocess.run(
        [AGV, "submit", str(path), "--server", service.url, "--pace", "2.5"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    run_id = proc.stdout.split()[0]
    with service.client() as client:
        assert client.get(f"/api/runs/{run_id}").json()["pace"] == 2.5
        client.post(f"/api/runs/{run_id}/cancel")
        wait_status(client, run_id, {"aborted"})


def test_unknown_pages_answer_404(service: Server) -> None:
    """A browser gets the dashboard's 404 page for an unknown run or page; an API client
    (and anything under /api) the JSON answer."""
    html = {"Accept": "text/html,application/xhtml+xml"}
    for path in ("/runs/doesnotexist", "/nowhere", "/runs/x/y"):
        page = httpx.get(service.url + path, headers=html, timeout=30)
        assert page.status_code == 404, path
        assert page.headers["content-type"].startswith("text/html") and "Not found" in page.text
    plain = httpx.get(service.url + "/nowhere", timeout=30)
    assert plain.status_code == 404 and plain.json() == {"detail": "Not Found"}
    api = httpx.get(service.url + "/api/nowhere", headers=html, timeout=30)
    assert api.status_code == 404 and api.headers["content-type"] == "application/json"
