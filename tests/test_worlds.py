"""Worlds: rasterisation, built-in worlds, the world loader and rooms files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from agv_mission.geometry import Pose2D, yaw_from_quaternion
from agv_mission.maps.builtin_worlds import (
    BUILTIN_WORLDS,
    DEPOT_COLUMNS,
    HOUSE_DOORS,
    RACK_XS,
    TB3_INNER_APOTHEM,
    small_house,
    turtlebot3_world,
)
from agv_mission.maps.costmap import INSCRIBED, Costmap, CostmapConfig
from agv_mission.maps.grid import FREE, OCCUPIED, UNKNOWN
from agv_mission.maps.rasterize import occupancy_mask, rasterize
from agv_mission.maps.rooms_file import RoomsFileError, load_rooms
from agv_mission.maps.ros_map import load_ros_map
from agv_mission.maps.world_loader import WorldError, load_world, occupied_runs
from agv_mission.maps.worlds import Box, Cylinder

BURGER_RADIUS = 0.105
INFLATION = 0.3
TB3_WAYPOINTS = [Pose2D(1.13, -1.6), Pose2D(0.13, 1.93)]
TB3_SPAWN = Pose2D(-2.0, -0.5, 0.0)


@pytest.fixture(scope="module")
def worlds():
    return {name: make() for name, make in BUILTIN_WORLDS.items()}


# --------------------------------------------------------------------------- rasterize


def test_rasterize_box_on_cell_boundaries_fills_exactly_its_cells() -> None:
    grid = rasterize([Box(0.5, 0.5, 0.2, 0.1)], [], (0.0, 1.0, 0.0, 1.0), 0.1, Pose2D(0.05, 0.05))
    assert (grid.width, grid.height) == (10, 10)
    occupied = np.argwhere(grid.data == OCCUPIED)
    assert {tuple(rc) for rc in occupied} == {(r, c) for r in (4, 5) for c in (3, 4, 5, 6)}
    assert grid.counts() == {"free": 92, "occupied": 8, "unknown": 0}


def test_rasterize_outside_and_enclosed_space_is_unknown() -> None:
    ring = [Box(0.0, 1.0, 1.05, 0.05), Box(0.0, -1.0, 1.05, 0.05)]
    ring += [Box(1.0, 0.0, 0.05, 1.05), Box(-1.0, 0.0, 0.05, 1.05)]
    pillar = Cylinder(0.5, 0.5, 0.2)
    grid = rasterize(ring, [pillar], (-2.0, 2.0, -2.0, 2.0), 0.05, Pose2D(-0.5, -0.5))
    assert grid.value_at(np.array([-0.5, -0.5])) == FREE
    assert grid.value_at(np.array([1.5, 1.5])) == UNKNOWN  # outside the walls
    assert grid.value_at(np.array([1.0, 0.0])) == OCCUPIED
    assert grid.value_at(np.array([0.5, 0.5])) == OCCUPIED
    # Cylinder cells: exactly those whose square comes within the radius of the centre.
    rows, cols = np.nonzero(occupancy_mask([], [pillar], grid.data.shape, 0.05, grid.origin))
    centres = grid.cell_to_world(rows, cols)
    gap = np.maximum(np.abs(centres - [0.5, 0.5]) - 0.025, 0.0)
    assert np.all(np.hypot(gap[:, 0], gap[:, 1]) < 0.2)
    assert len(rows) == pytest.approx(math.pi * 0.25**2 / 0.05**2, rel=0.25)
    # The world outside, sealed off from the spawn, is unknown, not free.
    outside_spawn = rasterize(ring, [], (-2.0, 2.0, -2.0, 2.0), 0.05, Pose2D(1.5, 1.5))
    assert outside_spawn.value_at(np.array([0.0, 0.0])) == UNKNOWN


def test_rasterize_rotated_box() -> None:
    box = Box(0.0, 0.0, 1.0, 0.05, math.pi / 4)
    mask = occupancy_mask([box], [], (60, 60), 0.05, Pose2D(-1.5, -1.5))
    rows, cols = np.nonzero(mask)
    xy = np.stack([-1.5 + (cols + 0.5) * 0.05, -1.5 + (rows + 0.5) * 0.05], axis=1)
    along = (xy[:, 0] + xy[:, 1]) / math.sqrt(2)
    across = (xy[:, 1] - xy[:, 0]) / math.sqrt(2)
    assert np.all(np.abs(along) < 1.0 + 0.05) and np.all(np.abs(across) < 0.05 + 0.036)
    assert mask[30, 30] and not mask[30, 50]


def test_rasterize_rejects_a_bad_spawn() -> None:
    with pytest.raises(ValueError, match="inside an obstacle"):
        rasterize([Box(0, 0, 1, 1)], [], (-2, 2, -2, 2), 0.05, Pose2D(0.0, 0.0))
    with pytest.raises(ValueError, match="outside the bounds"):
        rasterize([], [], (-2, 2, -2, 2), 0.05, Pose2D(5.0, 0.0))


# --------------------------------------------------------------------------- built-in worlds


def test_builtin_world_names_and_maps(worlds) -> None:
    assert set(worlds) == {"turtlebot3_world", "small_house", "warehouse", "depot"}
    for name, world in worlds.items():
        assert world.name == name
        assert world.map.resolution == 0.05
        assert world.map.origin.yaw == 0.0
        assert world.rooms
        counts = world.map.counts()
        assert counts["free"] > 0 and counts["occupied"] > 0 and counts["unknown"] > 0
        # Map border is unknown: the outside of the arena, like a map_saver map.
        border = np.concatenate([world.map.data[0], world.map.data[-1]])
        assert np.all(border == UNKNOWN)


@pytest.mark.parametrize("name", sorted(BUILTIN_WORLDS))
def test_spawn_and_anchors_are_free_and_inside_their_rooms(worlds, name: str) -> None:
    world = worlds[name]
    costmap = Costmap.from_grid(world.map, BURGER_RADIUS)
    spawn = np.array(world.spawn.xy)
    assert costmap.is_free(spawn, margin=INFLATION)
    for label, room in world.rooms.items():
        assert room.label == label
        assert room.anchor is not None
        xy = np.array(room.anchor.xy)
        assert room.contains(*xy), label
        assert costmap.is_free(xy, margin=0.2), label
        assert costmap.cost_at(xy) < INSCRIBED, label
    # Every anchor is reachable from the spawn with room to spare (in the house: even
    # outside the inflation; the TurtleBot3 pillars stand only 0.8 m apart).
    spare = BURGER_RADIUS + (INFLATION if name == "small_house" else 0.1)
    labels, _ = ndimage.label(costmap.distance > spare)
    spawn_label = labels[tuple(np.array(world.map.world_to_cell(spawn)))]
    for room in world.rooms.values():
        cell = tuple(np.array(world.map.world_to_cell(np.array(room.anchor.xy))))
        assert labels[cell] == spawn_label, room.label


def test_warehouse_aisles_are_long_and_wide_enough(worlds) -> None:
    """Every aisle between two racks is free for a waffle (with inflation to spare) over
    the whole 16 m of its block, and the cross aisle joins them all."""
    world = worlds["warehouse"]
    assert world.map.width * world.map.resolution >= 30.0
    assert world.map.height * world.map.resolution >= 50.0
    costmap = Costmap.from_grid(world.map, 0.22)
    for left, right in zip(RACK_XS, RACK_XS[1:], strict=False):
        x = (left + right) / 2.0
        ys = np.arange(-17.5, -2.5, 0.1)
        line = np.stack([np.full_like(ys, x), ys], axis=1)
        assert costmap.is_free(line, margin=0.2).all(), x
        rack = np.array([[left, -10.0], [right, 10.0]])
        assert not costmap.is_free(rack).any()


def test_depot_is_open_with_columns(worlds) -> None:
    world = worlds["depot"]
    costmap = Costmap.from_grid(world.map, 0.22)
    free = costmap.distance > 0.22 + 0.3
    assert free.mean() > 0.6  # mostly open floor
    for x, y in DEPOT_COLUMNS:
        assert not costmap.is_free(np.array([x, y]))


def test_turtlebot3_world_geometry() -> None:
    world = turtlebot3_world()
    assert world.spawn == TB3_SPAWN
    assert len(world.cylinders) == 9
    assert {(c.x, c.y) for c in world.cylinders} == {
        (x, y) for x in (-1.1, 0.0, 1.1) for y in (-1.1, 0.0, 1.1)
    }
    assert all(c.radius == 0.15 for c in world.cylinders)
    assert len(world.boxes) == 6
    assert all(min(b.half_x, b.half_y) <= 0.06 for b in world.boxes)  # thin walls


def test_turtlebot3_seed_poses_have_room_to_spare() -> None:
    world = turtlebot3_world()
    costmap = Costmap.from_grid(world.map, BURGER_RADIUS)
    normals = [math.radians(30 + 60 * k) for k in range(6)]
    for pose in [TB3_SPAWN, *TB3_WAYPOINTS]:
        # Exact distance to the walls' inner faces: beyond footprint + inflation.
        to_walls = min(
            TB3_INNER_APOTHEM - (pose.x * math.cos(n) + pose.y * math.sin(n)) for n in normals
        )
        assert to_walls > BURGER_RADIUS + INFLATION + 0.05, pose
        # Exact distance to the pillars' surfaces.
        to_pillars = min(math.hypot(pose.x - c.x, pose.y - c.y) - c.radius for c in world.cylinders)
        assert to_pillars > BURGER_RADIUS + 0.2, pose
        # And in the rasterised costmap.
        xy = np.array(pose.xy)
        assert costmap.clearance(xy) > BURGER_RADIUS + 0.25, pose
        assert costmap.cost_at(xy) < INSCRIBED
    # The seed's quaternion goal yaw is within the world's conventions.
    assert yaw_from_quaternion(0.0, 0.0, -0.64003024, -0.76812292098) == pytest.approx(
        1.389, abs=1e-3
    )


def test_turtlebot3_world_fits_the_real_map(ros_maps: Path) -> None:
    real = load_ros_map(ros_maps / "turtlebot3_world" / "map.yaml")
    mine = turtlebot3_world().map
    rows, cols = np.nonzero(real.data == FREE)
    assert np.mean(mine.value_at(real.cell_to_world(rows, cols)) == FREE) > 0.97
    rows, cols = np.nonzero(mine.data == FREE)
    assert np.mean(real.value_at(mine.cell_to_world(rows, cols)) == FREE) > 0.93
    # The real walls lie on ours: most real wall cells within 0.1 m of an occupied cell.
    near = ndimage.distance_transform_edt(mine.data != OCCUPIED) * mine.resolution
    rows, cols = np.nonzero(real.data == OCCUPIED)
    r, c = mine.world_to_cell(real.cell_to_world(rows, cols))
    assert np.mean(near[r, c] <= 0.1) > 0.85


def test_small_house_layout(worlds) -> None:
    world = worlds["small_house"]
    assert world.spawn == Pose2D(3.83, -1.23, 0.0)
    assert set(world.rooms) == {"bedroom", "livingroom", "recreationroom", "kitchen"}
    living = world.rooms["livingroom"]
    assert living.polygon == ((-2.3, -5.3), (4.6, -5.3), (4.6, 0.0), (-2.3, 0.0))
    assert living.anchor == Pose2D(3.0, -2.0, 0.0)
    assert living.contains(*world.spawn.xy)
    # About 19 x 11 m.
    rows, cols = np.nonzero(world.map.data == OCCUPIED)
    xy = world.map.cell_to_world(rows, cols)
    width, depth = np.ptp(xy[:, 0]) + 0.05, np.ptp(xy[:, 1]) + 0.05
    assert 18.0 < width < 20.0 and 10.5 < depth < 11.5
    # Room polygons do not overlap.
    samples = np.mgrid[-9.5:9.5:0.5, -5.5:5.5:0.5].reshape(2, -1).T + 0.01
    inside = np.array([[r.contains(x, y) for x, y in samples] for r in world.rooms.values()])
    assert inside.sum(axis=0).max() == 1
    # The simulator's view of the house (boxes) and the robot's map agree.
    assert not world.cylinders


def test_small_house_doors_are_wide_enough(worlds) -> None:
    world = worlds["small_house"]
    costmap = Costmap.from_grid(world.map, BURGER_RADIUS)
    for name, (axis, at, (lo, hi)) in HOUSE_DOORS.items():
        assert hi - lo >= 0.9, name
        mid = (lo + hi) / 2.0
        centre = np.array([at, mid] if axis == "x" else [mid, at])
        assert costmap.clearance(centre) >= (hi - lo) / 2.0 - 0.06, name
        assert costmap.is_free(centre, margin=INFLATION), name


# --------------------------------------------------------------------------- world loader


def test_load_builtin_and_unknown_names(tmp_path: Path) -> None:
    assert load_world("small_house", tmp_path).name == "small_house"
    with pytest.raises(WorldError) as info:
        load_world("turtlebot4_world", tmp_path)
    message = str(info.value)
    assert "turtlebot4_world" in message
    assert "small_house" in message and "turtlebot3_world" in message
    with pytest.raises(WorldError, match="no such file"):
        load_world("maps/missing.yaml", tmp_path)


def test_load_ros_map_world_relative_to_base_dir(ros_maps: Path) -> None:
    world = load_world("turtlebot3_world/map.yaml", ros_maps)
    assert world.name == "turtlebot3_world"
    assert world.map.width == 384 and world.rooms == {} and world.cylinders == []
    costmap = Costmap.from_grid(world.map, BURGER_RADIUS)
    assert costmap.is_free(np.array(world.spawn.xy), margin=0.15)
    assert math.hypot(*world.spawn.xy) < 1.0  # near the map origin
    # A folder with a map.yaml works too.
    assert load_world(str(ros_maps / "aws_small_house"), Path("/")).map.width == 500


@pytest.mark.parametrize("name", ["turtlebot3_world", "aws_small_house"])
def test_ros_map_boxes_cover_exactly_the_occupied_cells(ros_maps: Path, name: str) -> None:
    world = load_world(str(ros_maps / name / "map.yaml"), Path("."))
    grid = world.map
    occupied = grid.data == OCCUPIED
    covered = occupancy_mask(world.boxes, [], grid.data.shape, grid.resolution, grid.origin)
    np.testing.assert_array_equal(covered, occupied)
    # Disjoint: the boxes' areas add up to the occupied cells.
    area = sum(4 * b.half_x * b.half_y for b in world.boxes) / grid.resolution**2
    assert area == pytest.approx(np.count_nonzero(occupied))
    assert len(world.boxes) < np.count_nonzero(occupied) / 3
    print(f"{name}: {np.count_nonzero(occupied)} occupied cells -> {len(world.boxes)} boxes")


def test_occupied_runs_merge_rows_then_stack() -> None:
    mask = np.zeros((5, 6), dtype=bool)
    mask[0:3, 1:4] = True  # one 3x3 block
    mask[3, 1:3] = True  # a shorter run below it
    mask[1, 5] = True
    rects = occupied_runs(mask)
    assert sorted(rects) == [(0, 2, 1, 3), (1, 1, 5, 5), (3, 3, 1, 2)]


def test_world_file(tmp_path: Path) -> None:
    (tmp_path / "rooms.yaml").write_text(
        "rooms:\n  den:\n    polygon: [[-1, -1], [1, -1], [1, 1], [-1, 1]]\n"
    )
    (tmp_path / "arena.yaml").write_text(
        """
spawn: {x: -0.5, y: -0.5}
resolution: 0.1
bounds: {xmin: -2, xmax: 2, ymin: -2, ymax: 2}
boxes:
  - {x: 0, y: 1.5, half_x: 1.6, half_y: 0.05}
  - {x: 0, y: -1.5, size: [3.2, 0.1]}
  - {x: 1.5, y: 0, half_x: 0.05, half_y: 1.6}
  - {x: -1.5, y: 0, half_x: 0.05, half_y: 1.6}
cylinders:
  - {x: 0.5, y: 0.5, radius: 0.2}
rooms: rooms.yaml
"""
    )
    world = load_world("arena.yaml", tmp_path)
    assert world.name == "arena"
    assert world.boxes[1] == Box(0.0, -1.5, 1.6, 0.05, 0.0)
    assert world.map.width == 40 and world.map.resolution == 0.1
    assert world.map.value_at(np.array([-0.5, -0.5])) == FREE
    assert world.map.value_at(np.array([1.8, 1.8])) == UNKNOWN
    assert set(world.rooms) == {"den"} and world.rooms["den"].anchor is None

    inline = tmp_path / "inline.yaml"
    inline.write_text(
        "name: tiny\nspawn: {x: 0, y: 0}\nboxes: [{x: 1, y: 0, half_x: 0.1, half_y: 1}]\n"
        "rooms: {a: {polygon: [[0, 0], [1, 0], [0, 1]], anchor: {x: 0.2, y: 0.2}}}\n"
    )
    tiny = load_world(str(inline), Path("/"))
    assert tiny.name == "tiny" and tiny.rooms["a"].anchor == Pose2D(0.2, 0.2, 0.0)
    assert tiny.map.extent == pytest.approx((-0.5, 1.6, -1.5, 1.5))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("boxes: []\n", "spawn: field required"),
        ("spawn: {x: 0, y: 0}\nboxes: [{x: 0, y: 0, half_x: 1}]\n", "boxes.0"),
        ("spawn: {x: 0, y: 0}\ncylinders: [{x: 0, y: 0, radius: -1}]\n", "cylinders.0.radius"),
        ("spawn: {x: 0, y: 0}\nboxs: []\n", "boxs"),
        (
            "spawn: {x: 0, y: 0}\nboxes: [{x: 0, y: 0, half_x: 1, half_y: 1}]\n",
            "inside an obstacle",
        ),
        ("spawn: {x: 0, y: 0}\nrooms: {r: {polygon: [[0, 0], [1, 1]]}}\n", "room 'r'"),
        ("just a string\n", "neither a ROS map YAML"),
    ],
)
def test_world_file_errors(tmp_path: Path, text: str, expected: str) -> None:
    (tmp_path / "w.yaml").write_text(text)
    with pytest.raises(WorldError) as info:
        load_world("w.yaml", tmp_path)
    assert expected in str(info.value)
    assert "w.yaml" in str(info.value)


def test_ros_map_errors_become_world_errors(tmp_path: Path) -> None:
    (tmp_path / "map.yaml").write_text("image: gone.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(WorldError, match="gone.pgm not found"):
        load_world("map.yaml", tmp_path)


# --------------------------------------------------------------------------- rooms files


def test_load_rooms_file(tmp_path: Path) -> None:
    path = tmp_path / "rooms.yaml"
    path.write_text(
        """rooms:
  livingroom:
    polygon: [[-2.3, -5.3], [4.6, -5.3], [4.6, 0.0], [-2.3, 0.0]]   # map frame, metres
    anchor: {x: 3.0, y: -2.0, yaw: 0.0}
  kitchen:
    polygon:
      - [4.8, -5.3]
      - [9.3, -5.3]
      - [9.3, 3.0]
"""
    )
    rooms = load_rooms(path)
    assert list(rooms) == ["livingroom", "kitchen"]
    assert rooms["livingroom"].polygon[1] == (4.6, -5.3)
    assert rooms["livingroom"].anchor == Pose2D(3.0, -2.0, 0.0)
    assert rooms["kitchen"].anchor is None
    assert rooms["livingroom"].contains(3.83, -1.23)
    # The small house's own rooms are consistent with the contract's example.
    assert small_house().rooms["livingroom"].polygon == rooms["livingroom"].polygon


@pytest.mark.parametrize(
    ("text", "room", "line", "expected"),
    [
        ("rooms:\n  hall:\n    polygon: [[0, 0], [1, 0]]\n", "hall", 3, "polygon"),
        ("rooms:\n  hall:\n    anchor: {x: 0, y: 0}\n", "hall", 2, "has no polygon"),
        (
            "rooms:\n  a:\n    polygon: [[0, 0], [1, 0], [0, 1]]\n  b:\n"
            "    polygon: [[0, 0], [1, 0], [0, 1]]\n    anchor: {x: 1}\n",
            "b",
            6,
            "the anchor has no 'y'",
        ),
        ("rooms:\n  flat:\n    polygon: [[0, 0], [1, 1], [2, 2]]\n", "flat", 3, "zero area"),
        (
            "rooms:\n  c:\n    polygon: [[0, 0], [1, 0], [0, 1]]\n    colour: red\n",
            "c",
            4,
            "unknown key 'colour'",
        ),
        (
            "rooms:\n  d:\n    polygon: [[0, 0], [1, 0], [0, x]]\n",
            "d",
            3,
            "polygon point 2: y must be a finite number, got 'x'",
        ),
    ],
)
def test_rooms_file_errors_name_file_line_and_room(
    tmp_path: Path, text: str, room: str, line: int, expected: str
) -> None:
    path = tmp_path / "bad_rooms.yaml"
    path.write_text(text)
    with pytest.raises(RoomsFileError) as info:
        load_rooms(path)
    message = str(info.value)
    assert f"{path}:{line}: room '{room}'" in message
    assert expected in message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (None, "not found"),
        ("rooms: [unclosed\n", "invalid YAML"),
        ("livingroom:\n  polygon: [[0, 0], [1, 0], [0, 1]]\n", "top-level 'rooms' key"),
    ],
)
def test_rooms_file_other_errors(tmp_path: Path, text: str | None, expected: str) -> None:
    path = tmp_path / "rooms.yaml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(RoomsFileError) as info:
        load_rooms(path)
    assert str(path) in str(info.value) and expected in str(info.value)


def test_costmap_resolution_resamples_the_map_without_opening_walls() -> None:
    """``stack.costmap.resolution`` coarsens conservatively: every wall cell of the map
    stays under an occupied costmap cell, and the free interior stays free."""
    grid = turtlebot3_world().map
    coarse = Costmap.from_grid(grid, 0.105, CostmapConfig(resolution=0.1))
    assert coarse.resolution == 0.1
    assert (coarse.grid.width, coarse.grid.height) == (
        math.ceil(grid.width / 2),
        math.ceil(grid.height / 2),
    )
    rows, cols = np.nonzero(grid.data == OCCUPIED)
    walls = grid.cell_to_world(rows, cols)
    assert np.all(coarse.grid.value_at(walls) == OCCUPIED)
    # A cell is free only where all four fine cells are free.
    fine_free = (grid.data == FREE)[: grid.height // 2 * 2, : grid.width // 2 * 2]
    blocks = fine_free.reshape(grid.height // 2, 2, grid.width // 2, 2).all(axis=(1, 3))
    assert np.array_equal(coarse.grid.data[: blocks.shape[0], : blocks.shape[1]] == FREE, blocks)
    # A finer costmap keeps every cell's value.
    fine = Costmap.from_grid(grid, 0.105, CostmapConfig(resolution=0.025))
    centres = fine.grid.cell_to_world(*np.indices(fine.grid.data.shape))
    assert np.array_equal(fine.grid.data, grid.value_at(centres))
