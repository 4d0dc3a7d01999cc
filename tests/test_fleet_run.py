"""Fleet missions end to end on the MuJoCo world: dispatched tasks queue behind a robot's
own, the fleet's log reaches result.json, and a robot whose tree is done still makes way."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.load.schema.expect import Expectations
from agv_mission.missions.report.expectations import check
from agv_mission.missions.report.outputs import open_run_dir, write_run
from agv_mission.missions.run.runner import run_mission

WORLDS = Path(__file__).parent / "worlds"

DISPATCHED = f"""\
name: dispatched
world: {WORLDS / "fleet_door.yaml"}
seed: 11
stack: {{localization: {{type: ground_truth}}, local_planner: {{type: pure_pursuit}}}}
robots:
  - name: west
    robot: burger
    start: {{x: -3.0, y: 0.0, yaw: 0.0}}
    tasks: [{{type: go_to, pose: {{x: -3.0, y: 1.2, yaw: 1.5708}}}}]
  - {{name: east, robot: burger, start: {{x: 3.0, y: 0.0, yaw: 3.1416}}}}
tasks:
  - {{type: go_to, pose: {{x: 2.5, y: -1.2, yaw: 0.0}}}}
  - {{type: go_to, pose: {{x: -2.5, y: -1.2, yaw: 0.0}}}}
  - {{type: go_to, pose: {{x: 3.0, y: 1.2, yaw: 0.0}}, robot: east}}
limits: {{time: 120}}
"""


def test_dispatched_tasks_go_to_the_quickest_robot_and_queue_behind_its_own(tmp_path):
    path = tmp_path / "dispatched.yaml"
    path.write_text(DISPATCHED)
    loaded = load_mission(path)
    run_dir = open_run_dir(tmp_path / "runs", loaded)
    record = run_mission(loaded, run_dir)
    write_run(run_dir, loaded, record)
    result = json.loads((run_dir / "result.json").read_text())
    assert result["status"] == "succeeded", result["reason"]
    # task 0 lies in the east room: east, holding its assigned task (a few seconds from
    # there), beats west, which would need the door; task 1, in the west room, goes to
    # west, behind its own task
    assert result["fleet"]["dispatch"] == [
        {"task": 1, "robot": "east", "t": 0.0},
        {"task": 2, "robot": "west", "t": 0.0},
    ]
    west, east = result["robots"]["west"], result["robots"]["east"]
    assert [t["status"] for t in west["tasks"]] == ["succeeded", "succeeded"]
    assert [t["status"] for t in east["tasks"]] == ["succeeded", "succeeded"]
    dispatch_events = [e for e in result["events"] if e["event"] == "dispatch"]
    assert {(e["robot"], e["task"]) for e in dispatch_events} == {("east", 1), ("west", 2)}
    assert result["fleet"]["robot_robot_collisions"] == 0
    expect = Expectations.model_validate(
        {
            "robot_robot_collisions_max": 0,
            "makespan_max": 120.0,
            "robots": {"west": {"tasks": ["succeeded", "succeeded"]}},
        }
    )
    assert check(expect, result) == []
    assert [f.metric for f in check(Expectations(makespan_max=1.0), result)] == ["makespan_max"]


@pytest.mark.slow  # 16 s of a fleet mapping
def test_a_fleet_robot_maps_from_its_own_start_and_rooms_reach_the_result(tmp_path):
    """The mixed house fleet: the mapper's SLAM is anchored at its own start (it once took
    the first robot's, 7.5 m away, and the fleet layer then saw it there), its map and
    the visitor's recorded rooms are in result.json, fleet-wide and per robot."""
    loaded = load_mission(Path(__file__).parent / "scenarios" / "slow" / "fleet_mixed_house.yaml")
    run_dir = open_run_dir(tmp_path / "runs", loaded)
    record = run_mission(loaded, run_dir)
    result = write_run(run_dir, loaded, record)
    assert result["status"] == "succeeded", result["reason"]
    [built] = result["maps"]
    assert built["robot"] == "mapper" and built["map"] == "bedroom_map"
    assert built["slam_rmse"] < 0.15 and built["free_iou"] > 0.8
    assert result["robots"]["mapper"]["maps"][0]["free_iou"] == built["free_iou"]
    assert (run_dir / "bedroom_map.yaml").is_file()
    rooms = result["rooms_recorded"]
    assert sorted(rooms) == ["bedroom", "kitchen"]
    assert result["robots"]["visitor"]["rooms_recorded"] == rooms
    for label, recorded in rooms.items():
        room = loaded.rooms[label]
        assert room.contains(recorded["x"], recorded["y"]), (label, recorded)


KIDNAP = """\
name: fleet-kidnap
world: turtlebot3_world
seed: 5
stack: {localization: {type: ground_truth}}
robots:
  - name: a
    robot: burger
    start: {x: -2.0, y: -0.5, yaw: 0.0}
    tasks: [{type: go_to, pose: {x: -1.6, y: -0.5, yaw: 0.0}}]
  - name: b
    robot: burger
    start: {x: -2.0, y: 0.5, yaw: 0.0}
    tasks: [{type: go_to, pose: {x: -1.6, y: 0.5, yaw: 0.0}}]
faults:
  - {type: kidnap, time: 1.0, pose: {x: 0.5, y: -1.5, yaw: 0.0}, robot: b}
  - {type: wheel_slip, factor: 0.2}
limits: {time: 4.0}
"""


def test_a_fault_aimed_at_one_robot_of_a_fleet_hits_only_it(tmp_path):
    path = tmp_path / "kidnap.yaml"
    path.write_text(KIDNAP)
    loaded = load_mission(path)
    record = run_mission(loaded)
    a, b = record.robots["a"], record.robots["b"]
    assert [f["type"] for f in a.extras["faults"]] == ["wheel_slip"]
    assert [(f["type"], f["fired"]) for f in b.extras["faults"]] == [
        ("kidnap", True),
        ("wheel_slip", True),
    ]

    def jumps(rows):  # the farthest the true position moved in one control step
        return float(np.hypot(*np.diff(rows[:, 1:3], axis=0).T).max())

    assert jumps(a.trajectory) < 0.05 < 2.0 < jumps(b.trajectory)
