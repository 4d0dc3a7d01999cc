"""The files a mission names, as a new user gets them wrong: rooms files with several
problems, rooms without an anchor, a map YAML that is not quite a map, unknown keys in
world and robot files."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np

from agv_mission.missions.load.loader import load_mission
from cli_in_process import agv

FOUR_PROBLEMS = """\
rooms:
  kitchen:
    polygon: [[0.0, 0.0], [1.0, 0.0]]
  hall:
    polygon: [[0, 0], [1, 0], [1], [0, 1]]
  den:
    polygon: [[0, 0], [2, 0], [2, 2], [0, 2]]
    anchor: {x: 5, y: 1}
  attic:
    polygn: [[0, 0], [2, 0], [2, 2]]
"""

# An L-shaped room in the house's living room: the mean of its vertices, (0.33, -3.2),
# lies outside it.
L_ROOM = """\
rooms:
  ell:
    polygon: [[-2.3, -5.3], [4.6, -5.3], [4.6, -4.3], [-1.3, -4.3], [-1.3, 0.0], [-2.3, 0.0]]
"""


def validate(*args: str) -> subprocess.CompletedProcess:
    """``agv-mission validate`` called in this process (test_cli.py starts the program)."""
    return agv("validate", *args)


def test_rooms_file_problems_one_per_line_in_the_tools_words(tmp_path: Path) -> None:
    rooms = tmp_path / "bad.rooms.yaml"
    rooms.write_text(FOUR_PROBLEMS)
    mission = tmp_path / "m.yaml"
    mission.write_text(
        f"world: small_house\nrooms: {rooms.name}\ntasks: [{{type: wander, duration: 1}}]\n"
    )
    r = validate(str(mission))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    lines = r.stderr.splitlines()
    assert lines[0] == "invalid input (5 problems):", r.stderr
    expected = [
        (3, "kitchen", "a room's polygon needs at least 3 points, this one has 2"),
        (5, "hall", "polygon point 2 must be [x, y] (two numbers), got [1.0]"),
        (8, "den", "anchor (5, 1) lies outside the room's polygon"),  # the anchor's line
        (9, "attic", "has no polygon"),
        (10, "attic", "unknown key 'polygn' (did you mean 'polygon'?)"),
    ]
    for line, room, message in expected:
        assert any(f"{rooms}:{line}: room '{room}': {message}" in text for text in lines), (
            line,
            r.stderr,
        )
    assert ";" not in r.stderr
    for raw in ("List should have", "field required", "polygon.2", "Input should"):
        assert raw not in r.stderr


def test_a_room_without_anchor_starts_and_is_visited_well_inside(tmp_path: Path) -> None:
    (tmp_path / "l.rooms.yaml").write_text(L_ROOM)
    mission = tmp_path / "m.yaml"
    mission.write_text(
        "world: small_house\nrooms: l.rooms.yaml\nstart: ell\n"
        "tasks: [{type: visit_rooms, rooms: [livingroom, ell]}]\n"
    )
    loaded = load_mission(mission)
    room = loaded.rooms["ell"]
    mean = np.mean(room.polygon, axis=0)
    assert not room.contains(*mean)  # the old start: outside the room
    start, goal = loaded.start, loaded.room_goals["ell"]
    assert room.contains(start.x, start.y) and room.contains(goal.x, goal.y)
    # Well inside: about half the arm's 1 m width from the outline, and clear of walls.
    assert loaded.costmap.clearance(np.array([start.x, start.y])) > 0.3
    assert room.inside_point() == (start.x, start.y)


def test_a_map_yaml_without_resolution_says_what_the_map_lacks(
    tmp_path: Path, ros_maps: Path
) -> None:
    pgm = (ros_maps / "turtlebot3_world" / "map.pgm").read_bytes()
    (tmp_path / "map.pgm").write_bytes(pgm)
    (tmp_path / "map.yaml").write_text("image: map.pgm\norigin: [-10.0, -10.0, 0.0]\n")
    mission = tmp_path / "m.yaml"
    mission.write_text("world: map.yaml\ntasks: [{type: wander, duration: 1}]\n")
    r = validate(str(mission))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert f"{mission}:1: world:" in r.stderr
    assert "the map YAML lacks 'resolution'" in r.stderr
    assert "spawn" not in r.stderr


def test_world_and_robot_files_suggest_the_nearest_key(tmp_path: Path) -> None:
    (tmp_path / "w.yaml").write_text(
        "spawn: {x: 0, y: 0}\nboxes: [{x: 2, y: 2, size: [1, 1], yw: 0}]\nwal_height: 1\n"
    )
    (tmp_path / "r.yaml").write_text("wheel_radius: 0.033\nwheel_sep: 0.16\n")
    mission = tmp_path / "m.yaml"
    mission.write_text("world: w.yaml\nrobot: r.yaml\ntasks: [{type: wander, duration: 1}]\n")
    r = validate(str(mission))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "boxes.0.yw: unknown key 'yw' (did you mean 'yaw'?)" in r.stderr
    assert "wal_height: unknown key 'wal_height' (did you mean 'wall_height'?)" in r.stderr
    mission.write_text("world: small_house\nrobot: r.yaml\ntasks: [{type: wander, duration: 1}]\n")
    r = validate(str(mission))
    assert r.returncode == 2
    assert "line 2: wheel_sep: unknown key 'wheel_sep' (did you mean 'wheel_separation'?)" in (
        r.stderr
    )


def test_world_file_problems_one_per_line(tmp_path: Path) -> None:
    (tmp_path / "w.yaml").write_text(
        "spawn: {x: 0, y: 0}\nrooms:\n  den:\n    polygon: [[0, 0], [1, 0]]\n"
        "  hall:\n    polygon: [[0, 0], [1, 0], [0, 1]]\n    anchor: {x: 3, y: 3}\n"
    )
    mission = tmp_path / "m.yaml"
    mission.write_text("world: w.yaml\ntasks: [{type: wander, duration: 1}]\n")
    r = validate(str(mission))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.splitlines()[0] == "invalid input (2 problems):"
    world = tmp_path / "w.yaml"
    assert f"{world}:4: room 'den': a room's polygon needs at least 3 points" in r.stderr
    assert f"{world}:7: room 'hall': anchor (3, 3) lies outside" in r.stderr
