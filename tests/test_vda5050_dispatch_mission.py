"""A mission file as the master reads it: the mission through the loader (a fleet as a
fleet), its tasks' dispatch-only ``actions:`` beside it, problems at the file's own lines."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from agv_mission.missions.load.errors import MissionError
from agv_mission.vda5050.dispatch_mission import load_dispatch_mission
from agv_mission.vda5050.routes import load_plan
from agv_mission.vda5050.vehicle_set import load_vehicles

FLEET = {
    "name": "aisles",
    "world": "warehouse",
    "stack": {"localization": {"type": "ground_truth"}},
    "robots": [
        {
            "name": "agv1",
            "robot": "waffle",
            "start": {"x": -3.0, "y": -22.0, "yaw": 1.57},
            "tasks": [
                {
                    "type": "patrol",
                    "waypoints": [{"x": -3.0, "y": -20.5}],
                    "actions": [{"type": "pick", "at": "wp1", "load_id": "crate1"}],
                }
            ],
        },
        {"name": "agv2", "robot": "waffle", "start": {"x": 3.0, "y": -22.0, "yaw": 1.57}},
    ],
    "tasks": [
        {"type": "go_to", "pose": {"x": 3.0, "y": -20.5}, "robot": "agv2"},
        {"type": "go_to", "pose": {"x": 2.0, "y": -20.0}, "actions": [{"type": "drop"}]},
    ],
    "limits": {"time": 40.0},
}


def write(path: Path, doc: dict) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_a_fleet_plan_comes_from_the_loaded_models(tmp_path: Path) -> None:
    path = write(tmp_path / "fleet.yaml", FLEET)
    plan = load_plan(path)
    assert plan.robots == ["agv1", "agv2"]
    # the robots' own tasks first, then the fleet's, each where it is written
    assert [(t.where, t.robot) for t in plan.tasks] == [
        ("robots.0.tasks.0", "agv1"),
        ("tasks.0", "agv2"),
        ("tasks.1", None),
    ]
    assert [a.type for a in plan.tasks[0].nodes[0].actions] == ["pick"]
    assert [a.type for a in plan.tasks[2].nodes[-1].actions] == ["drop"]
    # mission.yaml of the run: the fleet mission as loaded, without the dispatch-only field
    assert [r["name"] for r in plan.resolved["robots"]] == ["agv1", "agv2"]
    assert "actions" not in yaml.safe_dump(plan.resolved)
    # the vehicles take the same file, its actions ignored
    assert [v.serial for v in load_vehicles(path).vehicles] == ["agv1", "agv2"]


def test_problems_name_the_file_as_written_when_it_has_actions(tmp_path: Path) -> None:
    doc = copy.deepcopy(FLEET)
    doc["tasks"][1]["pose"] = {"x": -3.0, "y": -18.0}  # in a rack
    path = write(tmp_path / "bad.yaml", doc)
    with pytest.raises(MissionError) as exc:
        load_dispatch_mission(path)
    [problem] = exc.value.problems
    assert problem.field == "tasks.1.pose" and problem.line is not None
    lines = path.read_text().splitlines()
    assert "-18.0" in "\n".join(lines[problem.line - 1 : problem.line + 3])
    doc = copy.deepcopy(FLEET)
    doc["robots"][0]["tasks"][0]["actions"][0]["type"] = "lift"
    path = write(tmp_path / "lift.yaml", doc)
    with pytest.raises(MissionError) as exc:
        load_plan(path)
    [problem] = exc.value.problems
    assert problem.field == "robots.0.tasks.0.actions.0.type"
    assert "lift" in path.read_text().splitlines()[problem.line - 1]
