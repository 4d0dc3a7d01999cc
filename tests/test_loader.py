"""Mission loading: valid files resolve; invalid ones name file, line and field."""

from __future__ import annotations

import math
import os
from pathlib import Path

import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "missions" / "patrol.yaml"


def write(tmp_path: Path, text: str, name: str = "m.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def problems_of(path: Path, overrides: list[str] | None = None) -> list:
    with pytest.raises(MissionError) as info:
        load_mission(path, overrides)
    return info.value.problems


def test_demo_mission_resolves_with_quaternion_yaws() -> None:
    loaded = load_mission(DEMO)
    wps = loaded.mission.tasks[0].waypoints
    # q and -q are the same rotation: z = -0.16547, w = -0.98621 is +0.3325 rad about z
    assert wps[0].yaw == pytest.approx(2 * math.atan2(0.16547, 0.986213798314), abs=1e-5)
    assert wps[1].yaw == pytest.approx(2 * math.atan2(0.64003024, 0.76812292098), abs=1e-3)
    assert loaded.name == "tb3-patrol"
    assert loaded.start.x == -2.0


def test_packaged_demo_is_the_repository_demo() -> None:
    packaged = REPO / "src" / "agv_mission" / "data" / "missions" / "patrol.yaml"
    assert packaged.read_bytes() == DEMO.read_bytes()


# One problem each: (document, its line, its field, words its message holds).
ONE_PROBLEM = {
    "unknown_key": (
        "world: turtlebot3_world\ntasks:\n  - type: go_to\n    pose: {x: 0.5, y: -0.5}\n    speed: 3\n",
        (5, "tasks.0.speed"),
        ["unknown key"],
    ),
    "wrong_type": (
        "tasks:\n  - type: patrol\n    waypoints: [{x: 0.5, y: -0.5}]\n    loops: many\n",
        (4, "tasks.0.loops"),
        ["integer", "'many'"],
    ),
    "goal_inside_a_pillar": (
        "tasks:\n  - {type: go_to, pose: {x: 0.5, y: -0.5}}\n  - {type: go_to, pose: {x: 1.1, y: 1.1}}\n",
        (3, "tasks.1.pose"),
        ["obstacle"],
    ),
    "goal_outside_the_map": (
        "tasks:\n  - type: patrol\n    waypoints:\n      - {x: 0.5, y: -0.5}\n      - {x: 40.0, y: 0.0}\n",
        (5, "tasks.0.waypoints.1"),
        ["outside the map"],
    ),
    "non_unit_quaternion": (
        "tasks:\n  - type: go_to\n    pose:\n      position: {x: 0.5, y: -0.5, z: 0}\n"
        "      orientation: {x: 0, y: 0, z: 0.5, w: 0.5}\n",
        (3, "tasks.0.pose"),
        ["unit length"],
    ),
    "tilted_quaternion": (
        "start:\n  position: {x: -2, y: -0.5, z: 0}\n  orientation: {x: 0.7071068, y: 0, z: 0, w: 0.7071068}\n"
        "tasks: [{type: go_to, pose: {x: 0.5, y: -0.5}}]\n",
        (1, "start"),
        ["tilts"],
    ),
    "unknown_planner_name": (
        "stack:\n  global_planner: {type: ompl, planner: RRTFast}\ntasks: [{type: go_to, pose: {x: 0.5, y: -0.5}}]\n",
        (2, "stack.global_planner.planner"),
        ["RRTFast"],
    ),
    "unknown_plugin_type_lists_known_types": (
        "stack:\n  local_planner: {type: dwa}\ntasks: [{type: go_to, pose: {x: 0.5, y: -0.5}}]\n",
        (2, "stack.local_planner"),
        ["mpc", "pure_pursuit"],
    ),
    "empty_task_list": ("tasks: []\n", (1, "tasks"), []),
    "unknown_world": (
        "world: moon_base\ntasks: [{type: go_to, pose: {x: 0, y: 0}}]\n",
        (1, "world"),
        ["turtlebot3_world"],
    ),
    "unknown_robot": (
        "robot: r2d2\ntasks: [{type: wander, duration: 1}]\n",
        (1, "robot"),
        ["burger"],
    ),
}


@pytest.mark.parametrize("case", ONE_PROBLEM)
def test_one_problem_names_line_and_field(tmp_path: Path, case: str) -> None:
    text, (line, field), words = ONE_PROBLEM[case]
    [p] = problems_of(write(tmp_path, text))
    assert (p.line, p.field) == (line, field)
    assert all(word in p.message for word in words), p.message


def test_yaml_syntax_error_names_line(tmp_path: Path) -> None:
    path = write(tmp_path, "tasks:\n  - type: go_to\n    pose: {x: 1.0, y: 0.0\n")
    [p] = problems_of(path)
    assert p.line is not None and p.line >= 3
    assert "YAML syntax error" in p.message


def test_set_overrides_apply_and_are_blamed(tmp_path: Path) -> None:
    loaded = load_mission(DEMO, ["stack.global_planner.planner=RRTstar", "tasks.0.loops=1"])
    assert loaded.mission.stack.global_planner.planner == "RRTstar"
    assert loaded.mission.tasks[0].loops == 1
    loaded = load_mission(DEMO, ["stack.global_planner.type=grid_astar"])
    assert loaded.mission.stack.global_planner.type == "grid_astar"
    [p] = problems_of(DEMO, ["tasks.0.loops=0"])
    assert p.field == "tasks.0.loops" and "--set tasks.0.loops=0" in p.message


def test_seed_override_and_resolved_document(tmp_path: Path) -> None:
    loaded = load_mission(DEMO, seed=42)
    doc = loaded.resolved()
    assert doc["seed"] == 42
    assert doc["stack"]["local_planner"]["type"] == "mpc"
    assert doc["tasks"][0]["waypoints"][0].keys() == {"x", "y", "yaw"}


def test_relative_world_path_resolves_against_mission_dir(tmp_path: Path, ros_maps: Path) -> None:
    sub = tmp_path / "deep" / "er"
    sub.mkdir(parents=True)
    map_yaml = ros_maps / "turtlebot3_world" / "map.yaml"
    rel = os.path.relpath(map_yaml, sub)
    path = write(
        sub,
        f"world: {rel}\ntasks: [{{type: go_to, pose: {{x: 1.13, y: -1.6}}}}]\nstart: {{x: -2.0, y: -0.5}}\n",
    )
    loaded = load_mission(path)
    assert loaded.world.map.width == 384


def test_a_fleet_robot_s_xml_tree_file_resolves_absolute_in_the_resolved_document(
    tmp_path: Path,
) -> None:
    """The run directory's mission.yaml loads from anywhere: every robot's tree file too."""
    sub = tmp_path / "deep"
    sub.mkdir()
    (sub / "patrol_tree.xml").write_text((REPO / "missions" / "patrol_tree.xml").read_text())
    path = write(
        sub,
        "world: turtlebot3_world\n"
        "blackboard: {first: {x: 0.5, y: -1.6}, second: {x: -1.6, y: 0.55}}\n"
        "robots:\n"
        "  - {name: agv1, robot: burger, start: {x: -2.0, y: -0.5}, tree: patrol_tree.xml}\n"
        "  - {name: agv2, robot: burger, start: {x: 2.0, y: 0.5, yaw: 3.1416}}\n",
    )
    doc = load_mission(path).resolved()
    named = doc["robots"][0]["tree"]
    assert Path(named).is_absolute() and Path(named) == (sub / "patrol_tree.xml").resolve()
