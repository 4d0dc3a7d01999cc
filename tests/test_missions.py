"""Whole missions on the real stack: MuJoCo, OMPL, casadi, py_trees."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from agv_mission.geometry import wrap_angle
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.record import RunRecord
from agv_mission.missions.run.runner import run_mission

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "missions" / "patrol.yaml"


def true_pose_at(record: RunRecord, t: float) -> np.ndarray:
    row = record.trajectory[np.argmin(np.abs(record.trajectory[:, 0] - t))]
    return row[1:4]


def assert_patrol_reached(
    record: RunRecord, loaded, tol_xy: float = 0.10, tol_yaw: float = 0.2
) -> None:
    assert record.status == "succeeded", record.reason
    task = loaded.mission.tasks[0]
    wps = record.tasks[0]["waypoints"]
    assert len(wps) == task.loops * len(task.waypoints)
    for report in wps:
        goal = task.waypoints[report["waypoint"] - 1]
        assert report["status"] == "reached"
        x, y, yaw = true_pose_at(record, report["t"])
        assert math.hypot(x - goal.x, y - goal.y) <= tol_xy, report
        assert abs(wrap_angle(yaw - goal.yaw)) <= tol_yaw, report
    assert record.metrics["collisions"] == 0


def test_demo_patrol_reaches_every_waypoint() -> None:
    loaded = load_mission(DEMO)
    record = run_mission(loaded)
    assert_patrol_reached(record, loaded)
    assert record.metrics["navigation"]["controller_failures"] == 0


@pytest.mark.parametrize(
    "override",
    [
        "stack.global_planner.planner=RRTstar",
        "stack.global_planner.type=grid_astar",
        "stack.local_planner.type=pure_pursuit",
    ],
)
def test_demo_patrol_with_swapped_plugins(override: str) -> None:
    loaded = load_mission(DEMO, [override, "tasks.0.loops=1", "tasks.0.dwell=0"])
    record = run_mission(loaded)
    assert_patrol_reached(record, loaded)


def test_patrol_on_the_real_turtlebot3_ros_map(tmp_path: Path, ros_maps: Path) -> None:
    map_yaml = ros_maps / "turtlebot3_world" / "map.yaml"
    mission = tmp_path / "ros_patrol.yaml"
    mission.write_text(DEMO.read_text().replace("world: turtlebot3_world", f"world: {map_yaml}"))
    loaded = load_mission(mission, ["tasks.0.loops=1"])
    # The real map_saver map (384 x 384 cells, walls from its occupied cells), not the
    # built-in arena of the same name (140 cells wide, nine pillars as cylinders).
    assert (loaded.world.map.width, loaded.world.map.height) == (384, 384)
    assert loaded.world.cylinders == [] and len(loaded.world.boxes) > 100
    record = run_mission(loaded)
    assert_patrol_reached(record, loaded)


def test_same_seed_same_trajectory() -> None:
    a = run_mission(
        load_mission(DEMO, ["tasks.0.loops=1", "tasks.0.waypoints=[{x: 1.13, y: -1.6}]"])
    )
    b = run_mission(
        load_mission(DEMO, ["tasks.0.loops=1", "tasks.0.waypoints=[{x: 1.13, y: -1.6}]"])
    )
    assert a.status == b.status == "succeeded"
    np.testing.assert_array_equal(a.trajectory, b.trajectory)


def test_wander_keeps_clear_of_obstacles() -> None:
    loaded = load_mission(DEMO, ["tasks=[{type: wander, duration: 40, min_range: 0.5}]"])
    record = run_mission(loaded)
    assert record.status == "succeeded"
    assert record.sim_time == pytest.approx(40.0, abs=0.11)
    assert record.metrics["collisions"] == 0
    assert record.metrics["distance_driven"] > 2.0  # it drove, not just spun
    turning = np.count_nonzero((record.trajectory[:, 7] < 1e-3) & (record.trajectory[:, 8] > 0.1))
    assert turning > 0  # it met an obstacle and turned away


def test_go_to_in_small_house_across_rooms() -> None:
    loaded = load_mission(
        DEMO,
        [
            "world=small_house",
            "start=null",
            "tasks=[{type: go_to, pose: {x: -3.0, y: 2.0, yaw: 1.57}}]",
            "limits.time=200",
        ],
    )
    record = run_mission(loaded)
    assert record.status == "succeeded", record.reason
    x, y, _ = record.trajectory[-1, 1:4]
    assert math.hypot(x + 3.0, y - 2.0) < 0.1
