"""``--set`` / ``--sweep`` in a defined order with nothing lost, errors that name the option
they came from, "did you mean" for unknown keys, and ROS-style poses that name their keys."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from cli_in_process import agv

COST_GRID_MISSION = """\
world: turtlebot3_world
start: {x: -2.0, y: -0.5}
stack:
  global_planner: {type: cost_grid, clearance: 0.1, max_detour: 1.5}
tasks:
  - type: patrol
    dwell: 0.5
    waypoints: [{x: -1.6, y: -0.5}]
"""

PLANNER = "stack.global_planner.planner=RRTstar"
TO_OMPL = "stack.global_planner.type=ompl"
TO_COST_GRID = "stack.global_planner.type=cost_grid"


def cli(*args: str) -> subprocess.CompletedProcess:
    """The command's answer, called in this process (test_cli.py starts the program)."""
    return agv(*args)


@pytest.fixture
def mission(tmp_path: Path) -> Path:
    path = tmp_path / "m.yaml"
    path.write_text(COST_GRID_MISSION)
    return path


def planner_block(path: Path, overrides: list[str]) -> dict:
    return load_mission(path, overrides).resolved()["stack"]["global_planner"]


def test_a_later_type_keeps_what_earlier_overrides_wrote(mission: Path) -> None:
    forward = planner_block(mission, [PLANNER, TO_OMPL])
    reverse = planner_block(mission, [TO_OMPL, PLANNER])
    assert forward == reverse
    assert (forward["type"], forward["planner"]) == ("ompl", "RRTstar")
    # The file's cost_grid keys went with the cost_grid plugin: OMPL's own defaults.
    assert "max_detour" not in forward


def test_a_whole_block_then_a_key_then_a_type_replays_in_order(mission: Path) -> None:
    block = planner_block(
        mission,
        ["stack.global_planner={type: ompl, planner: BITstar}", "stack.global_planner.planner=PRM"],
    )
    assert (block["type"], block["planner"]) == ("ompl", "PRM")


def test_a_key_the_final_plugin_lacks_names_both_options(mission: Path) -> None:
    with pytest.raises(MissionError) as caught:
        load_mission(mission, [TO_OMPL, PLANNER, TO_COST_GRID])
    [problem] = caught.value.problems
    assert problem.field == "stack.global_planner.planner"
    assert f"--set {PLANNER}" in problem.message
    assert f"--set {TO_COST_GRID}" in problem.message


def test_validate_takes_set_and_seed(mission: Path) -> None:
    ok = cli("validate", str(mission), "--set", PLANNER, "--set", TO_OMPL, "--seed", "7")
    assert ok.returncode == 0, ok.stderr
    bad = cli("validate", str(mission), "--set", TO_OMPL, "--set", PLANNER, "--set", TO_COST_GRID)
    assert bad.returncode == 2
    assert "unknown key 'planner'" in bad.stderr
    assert f"from --set {PLANNER}" in bad.stderr and TO_COST_GRID in bad.stderr
    seed = cli("validate", str(mission), "--seed", "-3")
    assert seed.returncode == 2 and "(from --seed -3)" in seed.stderr
    assert "Traceback" not in bad.stderr + seed.stderr


@pytest.mark.parametrize(
    ("text", "field", "suggestion"),
    [
        ("    dwel: 1\n", "tasks.0.dwel", "did you mean 'dwell'?"),
        ("limits: {tme: 3}\n", "limits.tme", "did you mean 'time'?"),
    ],
)
def test_unknown_keys_in_the_file_suggest_the_nearest(
    tmp_path: Path, text: str, field: str, suggestion: str
) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(COST_GRID_MISSION.replace("    dwell: 0.5\n", "    dwell: 0.5\n" + text, 1)
                    if text.startswith("    ") else COST_GRID_MISSION + text)  # fmt: skip
    r = cli("validate", str(path))
    assert r.returncode == 2
    line = 8 if text.startswith("    ") else 9
    assert f"{path}:{line}: {field}: unknown key" in r.stderr
    assert suggestion in r.stderr


def test_an_unknown_stack_slot_suggests_the_slot(mission: Path) -> None:
    r = cli("validate", str(mission), "--set", "stack.global_planer.planner=RRTstar")
    assert r.returncode == 2
    assert "unknown key 'global_planer' (did you mean 'global_planner'?)" in r.stderr
    assert "(from --set stack.global_planer.planner=RRTstar)" in r.stderr


def test_a_sweep_error_names_sweep(tmp_path: Path, mission: Path) -> None:
    r = cli(
        "regress",
        str(mission),
        "--sweep",
        "stack.global_planner.max_detur=1.2,1.4",
        "--output",
        str(tmp_path / "out"),
        "--workers",
        "1",
    )
    assert r.returncode == 2
    assert "(from --sweep stack.global_planner.max_detur=1.2)" in r.stderr
    assert "did you mean 'max_detour'?" in r.stderr
    assert "from --set" not in r.stderr and "Traceback" not in r.stderr


# ------------------------------------------------------------------------ ROS-style poses


@pytest.mark.parametrize(
    ("pose", "field", "message"),
    [
        ("{orientation: {z: 0, w: 1}}", "pose.position", "needs both 'position' and 'orientation'"),
        ("{position: {x: -1.6, y: -0.5}}", "pose.orientation", "needs both"),
        ("{position: {x: -1.6, y: -0.5}, orientation: {z: 0}}", "pose.orientation.w", "missing"),
        ("{position: {x: -1.6}, orientation: {z: 0, w: 1}}", "pose.position.y", "missing"),
        ("{position: {x: -1.6, y: -0.5}, orientation: {z: 0, w: 1, q: 0}}",
         "pose.orientation.q", "unknown key 'q'"),
    ],
)  # fmt: skip
def test_a_ros_pose_needs_position_and_orientation(
    tmp_path: Path, pose: str, field: str, message: str
) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: turtlebot3_world\nstart: {x: -2.0, y: -0.5}\ntasks:\n"
        f"  - type: go_to\n    pose: {pose}\n"
    )
    with pytest.raises(MissionError) as caught:
        load_mission(path)
    [problem] = caught.value.problems
    assert (problem.line, problem.field) == (5, f"tasks.0.{field}")
    assert message in problem.message


def test_a_complete_ros_pose_is_the_planar_pose(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: turtlebot3_world\nstart: {x: -2.0, y: -0.5}\ntasks:\n"
        "  - type: go_to\n    pose: {position: {x: -1.6, y: -0.5}, "
        "orientation: {z: 0.7071068, w: 0.7071068}}\n"
    )
    pose = load_mission(path).mission.tasks[0].pose
    assert (pose.x, pose.y) == (-1.6, -0.5)
    assert pose.yaw == pytest.approx(1.5707963, abs=1e-6)


def test_teleop_options_are_named_in_their_errors() -> None:
    r = agv("teleop", "--world", "nowhere", "--robot", "r2d2", input="")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "(from --world nowhere)" in r.stderr


def test_one_spelling_of_a_field_path_brackets_taken_with_a_hint(mission: Path) -> None:
    """``tasks.0.loops`` is the spelling of every message (command line and service);
    ``--set tasks[0].loops=2`` is taken as it, with a hint naming the accepted spelling."""
    loaded = load_mission(mission, ["tasks[0].loops=2", "tasks[0].waypoints[0].x=-1.5"])
    patrol = loaded.mission.tasks[0]
    assert patrol.loops == 2 and patrol.waypoints[0].x == -1.5
    hints = [str(w) for w in loaded.warnings]
    assert len(hints) == 2 and "is spelled tasks.0.loops" in hints[0]
    assert "tasks.0.waypoints.0.x" in hints[1]
    assert load_mission(mission, ["tasks.0.loops=2"]).warnings == []  # the spelling: no hint
    with pytest.raises(MissionError) as exc:  # problems spell the path one way
        load_mission(mission, ["tasks[0].loops=0"])
    assert exc.value.problems[0].field == "tasks.0.loops"
    done = cli("validate", str(mission), "--set", "tasks[0].loops=2")
    assert done.returncode == 0 and "is spelled tasks.0.loops" in done.stderr
