"""``map: none``: a robot that knows nothing of the world (robots-and-worlds.md)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from agv_mission.maps.grid import FREE
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import MissionRun

BARN = Path(__file__).parent / "data" / "barn"
START = {"x": -2.25, "y": 3.0, "yaw": 1.5707963}
GOAL = {"x": -2.25, "y": 13.0, "yaw": 1.5707963}


def barn_mission(tmp_path: Path, **changes: object) -> Path:
    """BARN's world 0 written by hand as a mission, beside a copy of the world."""
    shutil.copy(BARN / "world_0.world", tmp_path / "world_0.world")
    doc = {
        "world": "world_0.world",
        "map": "none",
        "robot": "jackal",
        "start": START,
        "stack": {"localization": {"type": "odometry"}},
        "tasks": [{"type": "go_to", "pose": GOAL}],
        "limits": {"time": 60.0},
        **changes,
    }
    path = tmp_path / "barn.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_amcl_is_refused_with_the_reason(tmp_path):
    path = barn_mission(tmp_path, stack={"localization": {"type": "amcl"}})
    with pytest.raises(MissionError) as err:
        load_mission(path)
    (problem,) = err.value.problems
    assert problem.field == "stack.localization.type"
    assert "map: none" in problem.message and "odometry" in problem.message


def test_a_mission_that_names_no_localisation_uses_odometry(tmp_path):
    path = barn_mission(tmp_path, stack={})
    assert load_mission(path).mission.stack.localization.type == "odometry"


def test_the_grid_covers_the_world_the_start_and_the_goals_plus_2_m(tmp_path):
    loaded = load_mission(barn_mission(tmp_path))
    # the world's extent: its cylinders' bounds (x -4.5..0, y 0..9.6) + 2 m; the goal
    # at y = 13 widens it to 15
    assert loaded.world.map.extent == pytest.approx((-6.5, 2.0, -2.0, 11.6))
    assert loaded.map.extent == pytest.approx((-6.5, 2.0, -2.0, 15.0))
    assert np.all(loaded.map.data == FREE)
    inner = int(1.0 / loaded.map.resolution)  # the costmap's edge is the map's border
    assert np.all(loaded.costmap.cost[inner:-inner, inner:-inner] == 0)


def test_a_goal_is_checked_only_against_that_grid(tmp_path):
    inside_a_pillar = {"x": -0.075, "y": 0.075, "yaw": 0.0}
    path = barn_mission(tmp_path, tasks=[{"type": "go_to", "pose": inside_a_pillar}])
    load_mission(path)  # the robot has not seen the pillar: a valid goal
    with pytest.raises(MissionError) as err:
        load_mission(path, ["map=null"])  # the world's own map has it
    assert err.value.problems[0].field == "tasks.0.pose"
    far = {"x": 5000.0, "y": 0.0, "yaw": 0.0}
    with pytest.raises(MissionError) as err:
        load_mission(barn_mission(tmp_path, tasks=[{"type": "go_to", "pose": far}]))
    assert err.value.problems[0].field == "map"
    assert "cells" in err.value.problems[0].message


def test_the_obstacle_layer_marks_what_the_lidar_sees(tmp_path):
    # localised by the truth: where the marks are is then the layer's doing alone
    stack = {"localization": {"type": "ground_truth"}}
    loaded = load_mission(barn_mission(tmp_path, limits={"time": 3.0}, stack=stack))
    run = MissionRun(loaded, None)
    layer = run.navigator.layer
    assert not layer.marks.any()
    while run.step():
        pass
    grid = layer.static.grid
    rows, cols = np.nonzero(layer.marks)
    assert len(rows) > 50
    centres = grid.cell_to_world(rows, cols)
    pillars = np.array([[c.x, c.y, c.radius] for c in loaded.world.cylinders])
    gap = np.hypot(*(centres[:, None, :] - pillars[None, :, :2]).transpose(2, 0, 1))
    gap = (gap - pillars[None, :, 2]).min(axis=1)
    # every mark is a pillar's surface: to the cell's half diagonal (0.035 m) and four
    # standard deviations of the UST-10LX's range noise (0.02 m); most much nearer
    assert np.all(gap < 0.035 + 4 * 0.02), gap.max()
    assert np.median(gap) < 0.03
    # and the planner's costmap holds them
    assert np.all(layer.costmap.distance[rows, cols] == 0)


@pytest.mark.slow
def test_a_barn_world_written_by_hand_runs(tmp_path):
    path = barn_mission(tmp_path, output="runs")
    done = subprocess.run(
        [sys.executable, "-m", "agv_mission.cli", "run", str(path), "--no-bag"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    (result,) = (tmp_path / "runs").glob("*/result.json")
    doc = json.loads(result.read_text())
    assert doc["status"] == "succeeded" and doc["metrics"]["collisions"] == 0
    trajectory = np.genfromtxt(result.parent / "trajectory.csv", delimiter=",", names=True)
    end = (trajectory["x"][-1], trajectory["y"][-1])
    assert np.hypot(end[0] - GOAL["x"], end[1] - GOAL["y"]) < 1.0
