"""A bad day: unmapped obstacles, recoveries, failure policies, collisions, interruptions."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Literal

import numpy as np
import pytest

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import write_run
from agv_mission.missions.run.runner import run_mission
from agv_mission.planners.base import VelocityCommand
from agv_mission.registry import PluginConfig, register

HOUSE = """
name: {name}
world: small_house
start: livingroom
seed: 1
stack:
  localization: {{type: ground_truth}}
obstacles:
{obstacles}
tasks:
{tasks}
limits: {{time: {time}}}
"""
KITCHEN_DOOR = "  - {type: box, x: 4.7, y: -2.8, size_x: 0.3, size_y: 1.5}"
KITCHEN_BACK_DOOR = "  - {type: box, x: 4.7, y: 1.6, size_x: 0.3, size_y: 1.5}"


def mission(
    tmp_path: Path, name: str, obstacles: list[str], tasks: str, limit: float = 300
) -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(
        HOUSE.format(name=name, obstacles="\n".join(obstacles) or "  []", tasks=tasks, time=limit)
    )
    return path


def test_unmapped_box_in_a_doorway_is_driven_around(tmp_path: Path) -> None:
    path = mission(
        tmp_path, "detour", [KITCHEN_DOOR], "  - {type: go_to, pose: {x: 7.0, y: -2.0, yaw: 0.0}}"
    )
    record = run_mission(load_mission(path))
    assert record.status == "succeeded", record.reason
    assert record.metrics["collisions"] == 0
    assert record.metrics["navigation"]["replans"] >= 1
    # it went round through the recreation room, north of the blocked door
    assert record.trajectory[:, 2].max() > 0.5
    x, y = record.trajectory[-1, 1:3]
    assert np.hypot(x - 7.0, y + 2.0) < 0.1


def test_no_way_through_fails_the_waypoint_and_skip_goes_on(tmp_path: Path) -> None:
    tasks = (
        "  - type: patrol\n    on_failure: skip\n    waypoints:\n"
        "      - {x: 7.0, y: -2.0}\n      - {x: 2.0, y: -3.5}\n"
    )
    path = mission(tmp_path, "noway", [KITCHEN_DOOR, KITCHEN_BACK_DOOR], tasks)
    record = run_mission(load_mission(path))
    assert record.status == "succeeded", record.reason
    [task] = record.tasks
    assert task["status"] == "partial"
    first, second = task["waypoints"]
    assert first["status"] == "skipped" and "unreachable" in first["reason"]
    assert second["status"] == "reached"
    recoveries = record.metrics["navigation"]["recoveries"]
    assert set(recoveries) == {"clear_costmap", "spin", "wait", "back_up"}
    assert all(n == 1 for n in recoveries.values())  # bounded: each tried once


def test_no_way_through_aborts_by_default_with_the_reason(tmp_path: Path) -> None:
    path = mission(
        tmp_path,
        "abort",
        [KITCHEN_DOOR, KITCHEN_BACK_DOOR],
        "  - {type: go_to, pose: {x: 7.0, y: -2.0}}\n  - {type: go_to, pose: {x: 2.0, y: -3.5}}",
    )
    record = run_mission(load_mission(path))
    assert record.status == "failed"
    assert "task 1 (go_to) failed" in record.reason and "unreachable" in record.reason
    assert [t["status"] for t in record.tasks] == ["failed", "not_run"]
    assert record.sim_time < 300  # failed by reason, not by the time limit


def test_retry_policy_tries_again_then_fails(tmp_path: Path) -> None:
    tasks = "  - {type: go_to, on_failure: retry, retries: 2, pose: {x: 7.0, y: -2.0}}"
    path = mission(tmp_path, "retry", [KITCHEN_DOOR, KITCHEN_BACK_DOOR], tasks)
    record = run_mission(load_mission(path, ["stack.navigation.recoveries=[clear_costmap]"]))
    assert record.status == "failed"
    clears = record.metrics["navigation"]["recoveries"]["clear_costmap"]
    assert clears == 3  # one per attempt: the first and two retries


def test_collision_fails_the_mission_unless_allowed(tmp_path: Path) -> None:
    # wander with a tiny min_range drives into a wall (1 cm: less than it needs to stop),
    # with the collision monitor off (it would stop the robot short of the wall)
    path = mission(tmp_path, "crash", [], "  - {type: wander, duration: 60, min_range: 0.01}", 80)
    blind = "stack.collision_monitor.enabled=false"
    record = run_mission(load_mission(path, [blind]))
    assert record.status == "failed" and "collision" in record.reason
    assert record.metrics["collisions"] == 1
    record = run_mission(load_mission(path, [blind, "limits.collisions=100"]))
    assert record.status == "succeeded"
    assert record.metrics["collisions"] >= 1
    assert record.metrics["min_clearance"] < 0.01


class _Boom(RuntimeError):
    pass


class ExplodingConfig(PluginConfig):
    type: Literal["exploding"] = "exploding"


@register("local_planner", "exploding")
class ExplodingController:
    """A controller that crashes after two seconds: the run must still say what happened."""

    Config = ExplodingConfig

    def __init__(self, config, limits, robot_radius, control_period) -> None:  # noqa: ANN001
        self.calls = 0

    def reset(self) -> None:
        pass

    def compute(self, pose, velocity, path, goal, obstacles) -> VelocityCommand:  # noqa: ANN001
        self.calls += 1
        if self.calls > 20:
            raise _Boom("controller blew up")
        return VelocityCommand(0.1, 0.0)


def test_a_crash_still_writes_a_complete_result(tmp_path: Path) -> None:
    path = mission(tmp_path, "boom", [], "  - {type: go_to, pose: {x: 2.0, y: -3.5}}")
    loaded = load_mission(path)
    # registered after the schema was built, so swapped in directly rather than by --set
    stack = loaded.mission.stack.model_copy(update={"local_planner": ExplodingConfig()})
    loaded.mission = loaded.mission.model_copy(update={"stack": stack})
    loaded.robots = [replace(loaded.lead, stack=stack)]
    record = run_mission(loaded)
    assert record.status == "error"
    assert record.reason == "_Boom: controller blew up"
    assert record.tasks[0]["status"] == "aborted"
    result = write_run(tmp_path, loaded, record)
    assert json.loads((tmp_path / "result.json").read_text())["status"] == "error"
    assert result["sim_time"] == pytest.approx(2.0, abs=0.11)


def test_ctrl_c_writes_result_aborted_and_exits_130(tmp_path: Path) -> None:
    path = mission(tmp_path, "long", [], "  - {type: wander, duration: 5000, min_range: 0.5}", 6000)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "agv_mission.cli",
            "run",
            str(path),
            "--output",
            str(tmp_path / "out"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 60
    while not list((tmp_path / "out").glob("*/mission.yaml")) and time.time() < deadline:
        time.sleep(0.2)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    [run_dir] = (tmp_path / "out").iterdir()
    result = json.loads((run_dir / "result.json").read_text())
    assert result["status"] == "aborted" and "Ctrl-C" in result["reason"]
    # one row per step run before the stop (none if it came while the run was set up)
    rows = (run_dir / "trajectory.csv").read_text().count("\n") - 1
    steps = round(result["sim_time"] / 0.1)
    assert rows in ((steps, steps + 1) if rows else (0,))


def test_same_seed_gives_an_identical_trajectory_file(tmp_path: Path) -> None:
    """The demo twice at once (each loading the other's core): the same bytes."""
    repo = Path(__file__).resolve().parents[1]
    demo = repo / "missions" / "patrol.yaml"
    overrides = ["--set", "tasks.0.loops=1", "--set", "stack.localization.type=amcl"]
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "agv_mission.cli", "run", str(demo)]
            + ["--output", str(tmp_path / f"out{k}"), *overrides],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for k in range(2)
    ]
    outs = []
    for k, proc in enumerate(procs):
        _, stderr = proc.communicate(timeout=600)
        assert proc.returncode == 0, stderr
        [run_dir] = (tmp_path / f"out{k}").iterdir()
        outs.append((run_dir / "trajectory.csv").read_bytes())
    assert outs[0] == outs[1]
