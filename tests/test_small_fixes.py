"""Small defects: wander's clearance, --set on an omitted plugin block."""

from __future__ import annotations

from pathlib import Path

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import run_mission
from mission_texts import mission_file, tb3_mission

WANDER = tb3_mission(
    "{type: wander, duration: 60.0, min_range: 0.6}",
    limits="{time: 70.0, collisions: 100}",
    robot="waffle",
    yaw=0.5,
)


def test_wander_keeps_the_waffle_off_the_walls(tmp_path: Path) -> None:
    """The waffle (0.22 m radius) along walls: the cone of +-20 degrees alone let it scrape
    them (1 mm of clearance); the swept corridor of its width keeps it off."""
    record = run_mission(load_mission(mission_file(tmp_path, WANDER, "wander")))
    assert record.status == "succeeded", record.reason
    assert record.metrics["collisions"] == 0
    assert record.metrics["min_clearance"] >= 0.05
    assert record.metrics["distance_driven"] > 5.0  # it did wander


def test_set_a_plugin_option_when_the_block_is_omitted(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text("tasks: [{type: wander, duration: 5}]\n")
    loaded = load_mission(path, ["stack.global_planner.planner=RRTstar"])
    planner = loaded.mission.stack.global_planner
    assert (planner.type, planner.planner) == ("ompl", "RRTstar")
    loaded = load_mission(path, ["stack.localization.max_particles=1000"])
    localization = loaded.mission.stack.localization
    assert (localization.type, localization.max_particles) == ("amcl", 1000)


def test_a_block_without_type_is_the_one_plugin_with_its_keys(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(
        "stack:\n  global_planner: {connectivity: 16}\ntasks: [{type: wander, duration: 5}]\n"
    )
    assert load_mission(path).mission.stack.global_planner.type == "grid_astar"
    path.write_text(
        "stack:\n  global_planner: {clearance: 0.2}\ntasks: [{type: wander, duration: 5}]\n"
    )
    assert load_mission(path).mission.stack.global_planner.type == "cost_grid"
