"""``agv-mission world``: a world's extent, spawn, rooms and map to pick waypoints from;
and the run table's details kept apart."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from agv_mission.maps.builtin_worlds import small_house
from agv_mission.maps.grid import FREE, OCCUPIED
from agv_mission.maps.ros_map import load_ros_map
from agv_mission.missions.report.summary import task_rows
from cli_in_process import agv

EXE = [sys.executable, "-m", "agv_mission.cli"]


def cli(*args: str) -> subprocess.CompletedProcess:
    """The program in a process of its own (the other cases call it in this one)."""
    return subprocess.run([*EXE, *args], capture_output=True, text=True, timeout=300)


def test_world_prints_extent_spawn_and_rooms_and_saves_its_map(tmp_path: Path) -> None:
    r = cli("world", "small_house", "--save-map", str(tmp_path / "house"))
    assert r.returncode == 0, r.stderr
    house = small_house()
    xmin, xmax, ymin, ymax = house.map.extent
    first = r.stdout.splitlines()[0]
    assert first.startswith("small_house: ")
    assert f"x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g}" in first
    assert f"spawn: x {house.spawn.x:.2f}, y {house.spawn.y:.2f}" in r.stdout
    for label, room in house.rooms.items():
        row = next(line for line in r.stdout.splitlines() if line.split()[:1] == [label])
        assert row.split()[1:3] == [f"{room.anchor.x:.2f}", f"{room.anchor.y:.2f}"]
    for dock in house.docks.values():
        assert f"dock {dock.name}: x {dock.pose.x:.2f}, y {dock.pose.y:.2f}" in r.stdout
    assert house.docks and "docks: none" not in r.stdout
    saved = load_ros_map(tmp_path / "house.yaml")
    assert (saved.width, saved.height, saved.resolution) == (
        house.map.width,
        house.map.height,
        house.map.resolution,
    )
    assert saved.origin == house.map.origin
    np.testing.assert_array_equal(saved.data == OCCUPIED, house.map.data == OCCUPIED)
    np.testing.assert_array_equal(saved.data == FREE, house.map.data == FREE)


def test_world_without_anchors_lists_inside_points(tmp_path: Path) -> None:
    (tmp_path / "w.yaml").write_text(
        "spawn: {x: 0.5, y: 0.5}\nboxes: [{x: 3, y: 3, size: [0.5, 0.5]}]\n"
        "rooms:\n  ell:\n    polygon: [[0, 0], [4, 0], [4, 1], [1, 1], [1, 4], [0, 4]]\n"
    )
    r = agv("world", str(tmp_path / "w.yaml"))
    assert r.returncode == 0, r.stderr
    row = next(line for line in r.stdout.splitlines() if line.split()[:1] == ["ell"])
    x, y = map(float, row.split()[1:3])
    assert row.split()[-1] == "inside"
    assert (x <= 1.0 or y <= 1.0) and 0 < x < 4 and 0 < y < 4  # in the L, not at its mean


def test_an_unknown_world_exits_2_listing_the_known_ones() -> None:
    r = agv("world", "smal_house")
    assert r.returncode == 2
    assert "depot, small_house, turtlebot3_world, warehouse" in r.stderr
    assert "Traceback" not in r.stderr


def test_the_run_table_keeps_its_details_apart() -> None:
    task = {
        "index": 1,
        "type": "patrol",
        "status": "failed",
        "reason": "time limit reached",
        "waypoints": [{"status": "reached"}, {"status": "unreachable"}],
        "waypoints_planned": 4,
    }
    [(_, _, detail)] = task_rows({"tasks": [task]})
    assert detail == "1/4 waypoints reached; time limit reached"
