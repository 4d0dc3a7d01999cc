"""Room visits and recording: the seed's room assignment as a mission."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from agv_mission.maps.builtin_worlds import small_house
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.rooms import reachable_cells, visit_point
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import run_mission

REPO = Path(__file__).resolve().parents[1]
VISIT = REPO / "missions" / "visit_rooms.yaml"
CONTRACT_KEYS = {"position": ["x", "y", "z"], "orientation": ["x", "y", "z", "w"]}


def test_visit_point_is_inside_reachable_and_clear() -> None:
    world = small_house()
    costmap = Costmap.from_grid(world.map, 0.105)
    allowed = reachable_cells(costmap, world.spawn, margin=0.1)
    for room in world.rooms.values():
        p = visit_point(room, costmap, allowed)
        assert p is not None and room.contains(p.x, p.y)
        assert costmap.clearance(np.array([p.x, p.y])) > 0.4


def test_unknown_room_label_lists_known_labels(tmp_path: Path) -> None:
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: small_house\ntasks:\n  - type: visit_rooms\n    rooms: [kitchen, garage]\n"
    )
    with pytest.raises(MissionError) as info:
        load_mission(path)
    [p] = info.value.problems
    assert (p.line, p.field) == (4, "tasks.0.rooms.1")
    assert "garage" in p.message and "bedroom, kitchen, livingroom, recreationroom" in p.message


def test_rooms_without_anchor_are_visited_inside(tmp_path: Path) -> None:
    rooms = tmp_path / "rooms.yaml"
    rooms.write_text(
        "rooms:\n  den:\n    polygon: [[-2.3, 0.0], [4.6, 0.0], [4.6, 5.3], [-2.3, 5.3]]\n"
    )
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: small_house\nrooms: rooms.yaml\nstart: livingroom\n"
        "tasks:\n  - {type: visit_rooms, rooms: [den], record: true}\n"
        "  - {type: record_room, room: den_again}\nlimits: {time: 200}\n"
    )
    loaded = load_mission(path)
    goal = loaded.room_goals["den"]
    assert loaded.rooms["den"].contains(goal.x, goal.y)
    record = run_mission(loaded, tmp_path)
    assert record.status == "succeeded", record.reason
    assert record.tasks[0]["rooms"] == [{"room": "den", "status": "reached", "recorded": True}]
    saved = yaml.safe_load((tmp_path / "location_recorder.yaml").read_text())
    assert list(saved) == ["den", "den_again"]


def test_visit_rooms_demo_records_every_room_inside_and_accurately(tmp_path: Path) -> None:
    loaded = load_mission(VISIT)
    record = run_mission(loaded, tmp_path)
    assert record.status == "succeeded", record.reason
    saved = yaml.safe_load((tmp_path / "location_recorder.yaml").read_text())
    assert list(saved) == ["livingroom", "recreationroom", "kitchen", "bedroom"]
    for label, entry in saved.items():
        assert {k: list(v) for k, v in entry.items()} == CONTRACT_KEYS
        x, y = entry["position"]["x"], entry["position"]["y"]
        assert loaded.rooms[label].contains(x, y)
        event = next(
            e for e in record.events if e["event"] == "room_recorded" and e["room"] == label
        )
        row = record.trajectory[np.argmin(np.abs(record.trajectory[:, 0] - event["t"]))]
        assert math.hypot(row[1] - x, row[2] - y) <= 0.1


def record_with_settle(tmp_path: Path, settle: float) -> float:
    path = tmp_path / f"settle{settle}.yaml"
    path.write_text(
        "world: small_house\nstart: livingroom\nseed: 4\n"
        "stack:\n  localization: {type: amcl, profile: recovery, initial_cov_xx: 0.01,"
        " initial_cov_yy: 0.01, initial_pose: {x: 3.1, y: -1.9, yaw: 0.05}}\n"
        f"tasks: [{{type: record_room, room: livingroom, settle: {settle}}}]\n"
    )
    loaded = load_mission(path)
    record = run_mission(loaded)
    assert record.status == "succeeded", record.reason
    assert np.abs(record.trajectory[:, 7:9]).max() == 0.0  # it never moved
    [event] = [e for e in record.events if e["event"] == "room_recorded"]
    assert event["t"] >= settle
    truth = loaded.start
    return math.hypot(event["x"] - truth.x, event["y"] - truth.y)


def test_record_room_settles_the_filter_before_recording(tmp_path: Path) -> None:
    """Standing still, amcl updates only on request (no-motion updates): ``settle`` lets a
    start guess 0.14 m off close in before the pose is recorded."""
    settled = record_with_settle(tmp_path, 2.0)
    unsettled = record_with_settle(tmp_path, 0.0)
    assert settled < 0.05
    assert settled < 0.5 * unsettled


def test_recorder_key_appends_to_an_existing_file(tmp_path: Path) -> None:
    existing = tmp_path / "location_recorder.yaml"
    existing.write_text(
        "garage:\n  position: {x: 1.0, y: 2.0, z: 0.0}\n"
        "  orientation: {x: 0.0, y: 0.0, z: 0.0, w: 1.0}\n"
    )
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: small_house\nstart: livingroom\nrecorder: location_recorder.yaml\n"
        "tasks: [{type: record_room, room: livingroom}]\n"
    )
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    record = run_mission(load_mission(path), run_dir)
    assert record.status == "succeeded"
    for file in (existing, run_dir / "location_recorder.yaml"):
        assert list(yaml.safe_load(file.read_text())) == ["garage", "livingroom"]


def test_malformed_recorder_file_is_invalid_input(tmp_path: Path) -> None:
    (tmp_path / "rec.yaml").write_text("kitchen: [1, 2]\n")
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: small_house\nrecorder: rec.yaml\ntasks: [{type: record_room, room: a}]\n"
    )
    with pytest.raises(MissionError) as info:
        load_mission(path)
    [p] = info.value.problems
    assert p.field == "recorder" and p.line == 2 and "kitchen" in p.message
