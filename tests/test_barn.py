"""``agv-mission barn`` (barn.md): BARN's protocol, its metric and the command."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agv_mission.barn import suite
from agv_mission.barn.protocol import BarnReferee, metric, path_length
from agv_mission.missions.run.runner import run_mission
from cli_in_process import agv as agv_here

BARN = Path(__file__).parent / "data" / "barn"
START, GOAL = (-2.25, 3.0), (-2.25, 13.0)
WORLD_KEYS = {"world", "status", "success", "time", "metric", "path_length", "run_dir"}


def runpy_path_length(k: int) -> float:
    """BARN's run.py, its own way: cells to Gazebo by path_coord_to_gazebo_coord
    (RADIUS 0.075), start and goal added, the polyline's length."""
    radius = 0.075
    r_shift, c_shift = -radius - (30 * radius * 2), radius + 5
    cells = np.load(BARN / "path_files" / f"path_{k}.npy")
    points = [START] + [(x * radius * 2 + r_shift, y * radius * 2 + c_shift) for x, y in cells]
    points.append(GOAL)
    return sum(
        float(np.hypot(b[0] - a[0], b[1] - a[1]))
        for a, b in zip(points[:-1], points[1:], strict=True)
    )


def recomputed(run_dir: Path, length: float) -> tuple[str | None, float, float]:
    """Status, time and metric from trajectory.csv alone: the clock from the first row
    0.1 m from the start, success at the first row within 1 m of the goal (true x, y)."""
    rows = np.genfromtxt(run_dir / "trajectory.csv", delimiter=",", names=True)
    t, x, y = rows["t"], rows["x"], rows["y"]
    moved = np.flatnonzero(np.hypot(x - START[0], y - START[1]) >= 0.1)
    clock = t[moved[0]] if len(moved) else 0.0
    arrived = np.flatnonzero(np.hypot(x - GOAL[0], y - GOAL[1]) <= 1.0)
    end = t[arrived[0]] if len(arrived) else t[-1]
    time = end - clock
    optimal = length / 2.0
    score = (1.0 if len(arrived) else 0.0) * optimal / np.clip(time, 2 * optimal, 8 * optimal)
    return ("succeeded" if len(arrived) else None), float(time), float(score)


def agv(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "agv_mission.cli", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=900,
    )


@pytest.mark.parametrize("k", [0, 1, 2])
def test_path_length_is_run_pys(k):
    assert path_length(BARN / "path_files" / f"path_{k}.npy") == pytest.approx(runpy_path_length(k))


def test_the_metric_is_clipped_between_2_and_8_optimal_times():
    assert metric(True, 5.0, 20.0) == pytest.approx(0.5)  # OT 10 s: faster than 2 OT
    assert metric(True, 40.0, 20.0) == pytest.approx(0.25)
    assert metric(True, 500.0, 20.0) == pytest.approx(0.125)
    assert metric(False, 40.0, 20.0) == 0.0


def test_world_selection():
    assert suite.parse_selection("0-2,5, 7-7") == [0, 1, 2, 5, 7]
    for bad in ("3-1", "a", "1,,2", "-4"):
        with pytest.raises(suite.BarnInputError):
            suite.parse_selection(bad)


def test_a_missing_path_file_is_invalid_input_naming_it(tmp_path):
    """Each answer called in this process; the run below starts the program."""
    shutil.copy(BARN / "world_0.world", tmp_path / "world_0.world")
    done = agv_here("barn", str(tmp_path), "--output", str(tmp_path / "runs"), cwd=tmp_path)
    assert done.returncode == 2
    assert str(tmp_path / "path_files" / "path_0.npy") in done.stderr
    done = agv_here("barn", str(BARN), "--worlds", "0,7", cwd=tmp_path)
    assert done.returncode == 2 and "world_7.world" in done.stderr
    done = agv_here(
        "barn", str(BARN), "--worlds", "0", "--set", "stack.local_planner.type=dwa", cwd=tmp_path
    )
    assert done.returncode == 2 and "--set stack.local_planner.type=dwa" in done.stderr


def test_barn_runs_a_world_by_its_protocol_and_the_metric_agrees_with_its_trajectory(tmp_path):
    out = tmp_path / "barn.json"
    done = agv(
        "barn", str(BARN), "--worlds", "0", "--workers", "1",
        "--output", str(tmp_path / "runs"), "--json", str(out), cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    doc = json.loads(out.read_text())
    (world,) = doc["worlds"]
    assert set(world) == WORLD_KEYS
    assert world["world"] == 0 and world["status"] in ("succeeded", "collided", "timeout", "failed")
    assert world["success"] == (world["status"] == "succeeded")
    assert world["path_length"] == pytest.approx(runpy_path_length(0))
    run_dir = Path(world["run_dir"])
    assert run_dir == tmp_path / "runs" / "world_0"
    for name in ("result.json", "trajectory.csv", "mission.yaml", "run.png", "tree.txt", "bag"):
        assert (run_dir / name).exists(), name
    result = json.loads((run_dir / "result.json").read_text())
    assert result["robot"] == "jackal" and result["barn"]["metric"] == world["metric"]
    status, time, score = recomputed(run_dir, world["path_length"])
    assert world["metric"] == pytest.approx(score, abs=1e-6)
    assert (status == "succeeded") == (world["status"] == "succeeded")
    if world["status"] in ("succeeded", "collided"):
        assert world["time"] == pytest.approx(time, abs=1e-6)
    elif world["status"] == "timeout":
        assert world["time"] == 100.0  # BARN's clock ran out (or would have: it stands)
    summary = doc["summary"]
    assert summary["worlds"] == 1
    assert summary["mean_metric"] == pytest.approx(world["metric"], abs=1e-4)
    assert "mean metric" in done.stdout and "world_0: " in done.stderr


def world_job(tmp_path: Path, k: int = 0, overrides: list[str] | None = None) -> dict:
    plan = suite.plan_worlds(BARN, str(k))
    return suite.world_jobs(plan, overrides or [], 0, tmp_path)[0]


def test_the_clock_runs_out_100_s_after_the_robot_moved(tmp_path):
    """A referee with a 1 s limit (BARN's is 100 s): the run ends 1 s after the robot is
    first 0.1 m from the start, a timeout scoring 0."""
    job = world_job(tmp_path)
    loaded = suite.load_world_mission(job)
    referee = BarnReferee(time_limit=1.0)
    record = run_mission(loaded, None, control=referee)
    outcome = referee.outcome(
        record.status, record.reason, record.trajectory, 0, job["path_length"]
    )
    assert outcome.status == "timeout" and outcome.metric == 0.0
    assert outcome.time == pytest.approx(1.0, abs=1e-6)
    t, x, y = record.trajectory[:, 0], record.trajectory[:, 1], record.trajectory[:, 2]
    moved = np.flatnonzero(np.hypot(x - START[0], y - START[1]) >= 0.1)[0]
    assert referee.clock == t[moved] and t[-1] == pytest.approx(t[moved] + 1.0)


def test_the_first_contact_is_a_collision(tmp_path):
    # carried into a pillar the robot has not seen (map: none lets the pose be)
    kidnap = "faults=[{type: kidnap, time: 0.5, pose: {x: -0.075, y: 0.075, yaw: 0.0}}]"
    job = world_job(tmp_path, 0, [kidnap])
    result = suite.run_world(job)
    assert result["status"] == "collided" and not result["success"] and result["metric"] == 0.0
    doc = json.loads((Path(result["run_dir"]) / "result.json").read_text())
    assert doc["metrics"]["collisions"] == 1 and doc["barn"]["status"] == "collided"


@pytest.mark.slow
def test_the_ray_backend_gives_the_local_results(tmp_path):
    pytest.importorskip("ray")
    plan = suite.plan_worlds(BARN, "1-2")
    from agv_mission.barn import workers

    local = workers.run_worlds(suite.world_jobs(plan, [], 0, tmp_path / "local"), "local", 2)
    remote = workers.run_worlds(suite.world_jobs(plan, [], 0, tmp_path / "ray"), "ray", 2)
    assert [r["world"] for r in remote] == [1, 2]
    for a, b in zip(local, remote, strict=True):
        assert (a["status"], a["time"], a["metric"]) == (b["status"], b["time"], b["metric"])
        assert Path(b["run_dir"]).parent == tmp_path / "ray"


def test_a_robot_that_stops_short_of_the_goal_is_a_timeout_without_simulating_the_wait(tmp_path):
    # navigation sent 3 m ahead only: it arrives there, stands, and the clock would run out
    job = world_job(tmp_path, 0, ["tree.children.0.child.pose.y=6.0", "output.bag=false"])
    result = suite.run_world(job)
    assert result["status"] == "timeout" and result["time"] == 100.0 and result["metric"] == 0.0
    doc = json.loads((Path(result["run_dir"]) / "result.json").read_text())
    assert doc["sim_time"] < 15.0 and "stands" in doc["reason"]
    rows = np.genfromtxt(Path(result["run_dir"]) / "trajectory.csv", delimiter=",", names=True)
    assert (
        abs(rows["y"][-1] - 6.0) < 0.5
        and np.hypot(rows["x"][-1] - GOAL[0], rows["y"][-1] - GOAL[1]) > 1.0
    )
