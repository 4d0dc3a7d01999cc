"""map_area and its bounds: out of sight is driven to, out of reach fails, and coverage
below the task's target is not success."""

from __future__ import annotations

from pathlib import Path

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import run_mission

ARENA = Path(__file__).resolve().parent / "invalid" / "data" / "arena.world.yaml"

# A 10 x 3 m corridor: from its west end the lidar (3.5 m) does not see the east end.
CORRIDOR = """\
name: corridor
resolution: 0.05
bounds: {xmin: -1.5, xmax: 9.5, ymin: -2.0, ymax: 2.0}
spawn: {x: 0.0, y: 0.0, yaw: 0.0}
boxes:
  - {x: 4.0, y: 1.55, half_x: 5.05, half_y: 0.05}
  - {x: 4.0, y: -1.55, half_x: 5.05, half_y: 0.05}
  - {x: -1.0, y: 0.0, half_x: 0.05, half_y: 1.6}
  - {x: 9.0, y: 0.0, half_x: 0.05, half_y: 1.6}
"""


def mission(tmp_path: Path, world: str, task: str, time: float = 150.0) -> Path:
    path = tmp_path / "m.yaml"
    path.write_text(
        f"world: {world}\n"
        "start: {x: 0.0, y: 0.0, yaw: 0.0}\n"
        "stack: {slam: {type: grid}, localization: {type: ground_truth}}\n"
        f"tasks:\n  - {task}\n"
        f"limits: {{time: {time}}}\n"
    )
    return path


def test_bounds_out_of_sight_are_driven_to_and_mapped(tmp_path: Path) -> None:
    (tmp_path / "corridor.world.yaml").write_text(CORRIDOR)
    task = (
        "{type: map_area, save_map: m, coverage: 0.9, "
        "bounds: {xmin: 6.0, xmax: 8.9, ymin: -1.45, ymax: 1.45}}"
    )
    record = run_mission(load_mission(mission(tmp_path, "corridor.world.yaml", task)))
    assert record.status == "succeeded", record.reason
    saved = next(e for e in record.events if e["event"] == "map_saved")
    assert saved["known_fraction"] >= 0.9
    assert record.trajectory[:, 1].max() > 3.0  # it drove east, towards the bounds


def test_bounds_that_cannot_be_reached_fail_with_a_reason(tmp_path: Path) -> None:
    """Beyond the arena's east wall: on the map, but no way leads there."""
    task = "{type: map_area, save_map: m, bounds: {xmin: 2.2, xmax: 2.9, ymin: -2.9, ymax: 2.9}}"
    record = run_mission(load_mission(mission(tmp_path, str(ARENA), task, 120.0)))
    assert record.status == "failed"
    assert record.tasks[0]["status"] == "failed"
    assert "cannot be reached" in record.tasks[0]["reason"]


def test_coverage_below_the_target_is_not_success(tmp_path: Path) -> None:
    (tmp_path / "corridor.world.yaml").write_text(CORRIDOR)
    task = "{type: map_area, save_map: m, coverage: 0.99, time_limit: 8.0}"
    record = run_mission(load_mission(mission(tmp_path, "corridor.world.yaml", task)))
    assert record.status == "failed"
    reason = record.tasks[0]["reason"]
    assert "below the 0.99 the task asks" in reason and "time limit" in reason
