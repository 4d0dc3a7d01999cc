"""Fleet missions on the one world: loading (names, starts, overrides), every robot a body
the others' lidars see, contacts between robots counted, outputs per robot."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.load.resolved import Layout
from agv_mission.missions.report.outputs import open_run_dir, write_run
from agv_mission.missions.run.fleet_orders import queue_fleet_tasks
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.missions.run.stack import build_world

FLEET = """\
name: pair
world: turtlebot3_world
seed: 3
stack: {{local_planner: {{type: pure_pursuit}}}}
robots:
  - name: agv1
    robot: burger
    start: {{x: {x1}, y: -0.5, yaw: 0.0}}
    tasks: [{{type: go_to, pose: {{x: -2.0, y: 1.0, yaw: 0.0}}}}]
  - name: agv2
    robot: waffle
    start: {{x: 2.0, y: 0.5, yaw: 3.14}}
    stack: {{local_planner: {{type: mpc}}}}
tasks:
  - {{type: go_to, pose: {{x: 1.8, y: -1.0, yaw: 0.0}}, robot: agv2}}
limits: {{time: 60}}
"""


def fleet_file(tmp_path, text=None, **fmt):
    path = tmp_path / "pair.yaml"
    path.write_text(text if text is not None else FLEET.format(**{"x1": -2.0, **fmt}))
    return path


def problems(path, overrides=()):
    with pytest.raises(MissionError) as err:
        load_mission(path, list(overrides))
    return [str(p) for p in err.value.problems]


def test_fleet_loads_each_robot_with_its_merged_stack(tmp_path):
    loaded = load_mission(fleet_file(tmp_path))
    assert loaded.layout is Layout.FLEET and [r.name for r in loaded.robots] == ["agv1", "agv2"]
    agv1, agv2 = loaded.robots
    assert agv1.stack.local_planner.type == "pure_pursuit"  # the mission's stack
    assert agv2.stack.local_planner.type == "mpc"  # its own, merged over
    assert agv2.robot.name == "waffle" and agv2.costmap is not agv1.costmap
    # the task assigned by robot: runs after agv2's own (none) once the run releases it
    assert agv2.tree is None and agv1.tree.task_types() == ["go_to"]
    agv1, agv2 = queue_fleet_tasks(loaded)[0].robots
    assert agv2.tree.task_types() == ["go_to"] and agv1.tree.task_types() == ["go_to"]
    swapped = load_mission(
        fleet_file(tmp_path), ["robots.agv1.stack.local_planner.type=mpc"]
    ).robots[0]
    assert swapped.stack.local_planner.type == "mpc"


def test_fleet_input_errors_name_the_robot_field(tmp_path):
    text = FLEET.format(x1=-2.0)
    both = fleet_file(tmp_path, "robot: burger\n" + text)
    assert any("robot" in p and "robots:" in p for p in problems(both))
    twice = fleet_file(tmp_path, text.replace("name: agv2", "name: agv1"))
    assert any("robots.1.name" in p and "used twice" in p for p in problems(twice))
    upper = fleet_file(tmp_path, text.replace("name: agv2", "name: AGV2"))
    assert any("robots.1.name" in p for p in problems(upper))
    stranger = fleet_file(tmp_path, text.replace("robot: agv2}", "robot: agv9}"))
    assert any("tasks.0.robot" in p and "agv9" in p for p in problems(stranger))
    close = fleet_file(tmp_path, text.replace("x: 2.0, y: 0.5", "x: -1.8, y: -0.45"))
    found = problems(close)
    assert any("robots.1.start" in p and "footprints" in p for p in found), found
    assert any("line" in p or ":" in p for p in found)
    unknown = problems(fleet_file(tmp_path), ["robots.agv7.start.x=1.0"])
    assert any("agv7" in p for p in unknown)


def test_every_lidar_sees_the_other_robots(tmp_path):
    text = FLEET.format(x1=1.0).replace("x: 2.0, y: 0.5", "x: 2.0, y: -0.5")
    loaded = load_mission(fleet_file(tmp_path, text))  # agv1 faces agv2, 1 m ahead
    world, stacks, _ = build_world(loaded)
    agv1, agv2 = stacks
    ranges = agv1.sim.scan().ranges
    ahead = float(np.nanmin(ranges[np.r_[0:5, -5:0]]))
    radius = loaded.robots[1].robot.footprint_radius
    assert ahead == pytest.approx(1.0 - radius, abs=0.08)  # the waffle's hull, not a wall
    own = agv2.sim.scan().ranges  # and the waffle sees the burger, never itself
    assert float(np.nanmin(own)) > 0.05


def test_robots_touching_count_as_robot_robot_collisions(tmp_path):
    text = FLEET.format(x1=1.2).replace("x: 2.0, y: 0.5", "x: 2.0, y: -0.5")
    loaded = load_mission(fleet_file(tmp_path, text), ["limits.collisions=5"])
    run = MissionRun(loaded, None)
    agv1, agv2 = run.robots
    where = []  # the burger's pose whenever a new touch was logged
    for _ in range(40):  # drive the burger straight into the waffle, blind
        now = run.world.time
        for r in run.robots:
            r.decide(now)
        logged = len(run.fleet_log["robot_robot_collisions"])
        run._watch_robots(now)
        if len(run.fleet_log["robot_robot_collisions"]) > logged:
            where.append(agv1.sim.true_pose())
        agv1.sim.set_command(0.2, 0.0)
        agv2.sim.set_command(0.0, 0.0)
        run.world.step(10)
    log = run.fleet_log
    assert log["robot_robot_collisions"], "the robots touched"
    assert log["robot_robot_min_distance"] < 0.01
    assert log["robot_robot_collisions"][0]["robots"] == ["agv1", "agv2"]
    first = log["robot_robot_collisions"][0]  # logged where the first of the two stood
    assert (first["x"], first["y"]) == (round(where[0].x, 3), round(where[0].y, 3))


def test_fleet_run_writes_results_per_robot(tmp_path):
    loaded = load_mission(fleet_file(tmp_path))
    run_dir = open_run_dir(tmp_path / "runs", loaded)
    record = run_mission(loaded, run_dir)
    result = write_run(run_dir, loaded, record)
    assert record.status == "succeeded", record.reason
    assert set(result["robots"]) == {"agv1", "agv2"}
    assert all(r["status"] == "succeeded" for r in result["robots"].values())
    fleet = result["fleet"]
    assert fleet["robot_robot_collisions"] == 0 and fleet["robot_robot_min_distance"] > 0.5
    assert fleet["makespan"] == pytest.approx(record.sim_time, abs=0.2)
    assert json.loads((run_dir / "result.json").read_text())["robots"]["agv2"]["robot"] == "waffle"
    with open(run_dir / "trajectory.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0])[0] == "robot"
    names = {r["robot"] for r in rows}
    assert names == {"agv1", "agv2"}
    per = {n: [float(r["t"]) for r in rows if r["robot"] == n] for n in names}
    assert per["agv1"] == per["agv2"]  # one row per robot per control step
    end = [r for r in rows if r["robot"] == "agv2"][-1]
    assert math.hypot(float(end["x"]) - 1.8, float(end["y"]) + 1.0) < 0.3
    assert (run_dir / "run.png").stat().st_size > 10_000


def test_one_robot_mission_is_a_world_with_one_robot(tmp_path):
    path = tmp_path / "one.yaml"
    path.write_text(
        "world: turtlebot3_world\nseed: 3\nstart: {x: -2.0, y: -0.5, yaw: 0.0}\n"
        "tasks: [{type: go_to, pose: {x: -2.0, y: 1.0, yaw: 0.0}}]\nlimits: {time: 40}\n"
    )
    run = MissionRun(load_mission(path), None)
    assert len(run.robots) == 1 and list(run.world.bodies) == ["robot"]
    a, b = run_mission(load_mission(path)), run_mission(load_mission(path))
    assert a.status == "succeeded" and np.array_equal(a.trajectory, b.trajectory)


def test_every_robots_problems_are_reported_together(tmp_path):
    """One robot's bad entry does not hide the next robot's, nor the fleet block's."""
    path = tmp_path / "bad.yaml"
    path.write_text(
        "world: turtlebot3_world\n"
        "robots:\n"
        "  - {name: agv1, start: {x: -2.0, y: -0.5}, robot: tank}\n"
        "  - {name: agv2, start: {x: 2.0, y: 0.5}, tasks: [{type: go_to, pose: {x: 9, y: 9}}]}\n"
        "  - {start: {x: 1.0, y: 0.5}}\n"
        "tasks:\n"
        "  - {type: go_to, pose: {x: 1.8, y: -1.0}, robot: 7}\n"
        "fleet: {dispatcher: {type: fastest}}\n"
    )
    found = problems(path)
    assert any(":7: tasks.0.robot" in p for p in found), found
    assert any(":5: robots.2.name" in p for p in found), found
    assert any(":8: fleet.dispatcher" in p and "quickest_finish" in p for p in found), found
    path.write_text(
        path.read_text()
        .replace("robot: 7}", "}")
        .replace("  - {start:", "  - {name: agv3, start:")
        .replace("fastest", "nearest_idle")
    )
    found = problems(path)
    assert any(":3: robots.0.robot" in p and "tank" in p for p in found), found
    assert any(":4: robots.1.tasks.0.pose" in p and "outside the map" in p for p in found), found
    not_a_list = tmp_path / "list.yaml"
    not_a_list.write_text("world: turtlebot3_world\nrobots: agv1\n")
    assert any(":2: robots" in p and "list" in p for p in problems(not_a_list))


def test_fleet_tasks_queue_in_the_order_given(tmp_path):
    """Assigned and dispatched tasks join a robot's tree in the order of `tasks:`, after its
    own (fleet.md), whichever way each came to it."""
    from agv_mission.missions.run.fleet_orders import tree_goals

    path = tmp_path / "order.yaml"
    path.write_text(
        "world: turtlebot3_world\n"
        "robots:\n"
        "  - name: agv1\n"
        "    start: {x: -2.0, y: -0.5}\n"
        "    tasks: [{type: go_to, pose: {x: -2.0, y: 1.0}}]\n"
        "tasks:\n"
        "  - {type: go_to, pose: {x: 1.8, y: -1.0}}\n"
        "  - {type: go_to, pose: {x: 1.8, y: 1.0}, robot: agv1}\n"
        "  - {type: go_to, pose: {x: 0.0, y: -2.0}}\n"
    )
    loaded, log = queue_fleet_tasks(load_mission(path))
    goals = [(g.x, g.y) for g in tree_goals(loaded.robots[0].tree, {}, {})]
    assert goals == [(-2.0, 1.0), (1.8, -1.0), (1.8, 1.0), (0.0, -2.0)]
    assert [d["task"] for d in log] == [1, 3] and {d["robot"] for d in log} == {"agv1"}
