"""Map-size-independent pieces: the rolling-window obstacle layer and the cached
distance transforms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, ObstacleLayerConfig
from agv_mission.maps.distance import obstacle_distance
from agv_mission.maps.grid import FREE, OCCUPIED, OccupancyGrid
from agv_mission.maps.obstacle_layer import ObstacleLayer
from agv_mission.sensor_msgs import LaserScan

BEAMS = 360


def room() -> OccupancyGrid:
    """A 10 x 10 m room at 5 cm, walls one cell thick, origin at (-5, -5)."""
    data = np.full((200, 200), FREE, dtype=np.int8)
    data[0], data[-1], data[:, 0], data[:, -1] = OCCUPIED, OCCUPIED, OCCUPIED, OCCUPIED
    return OccupancyGrid(data, 0.05, Pose2D(-5.0, -5.0))


def scan(ranges: dict[int, float], default: float = math.inf) -> LaserScan:
    r = np.full(BEAMS, default, dtype=np.float32)
    for i, v in ranges.items():
        r[i] = v
    return LaserScan(r, 0.0, 2 * math.pi / BEAMS, 0.12, 3.5, 0.0)


def layer() -> ObstacleLayer:
    return ObstacleLayer(Costmap.from_grid(room(), 0.1), ObstacleLayerConfig())


def test_unmapped_return_is_marked_and_cleared_when_seen_through():
    obs = layer()
    pose = Pose2D(0.0, 0.0, 0.0)
    assert obs.update(pose, scan({0: 1.0}))  # something 1 m ahead
    assert obs.marks.sum() == 1
    assert obs.costmap.clearance(np.array([[1.0, 0.0]]))[0] == 0.0
    # The obstacle left: the beam now reaches 2 m, through the marked cell.
    assert obs.update(pose, scan({0: 2.0}))
    assert obs.marks[obs.static.grid.world_to_cell(np.array([1.0, 0.0]))] == np.False_
    assert obs.marks.sum() == 1  # the new return, 2 m ahead
    assert obs.costmap.clearance(np.array([[1.0, 0.0]]))[0] > 0.5


def test_returns_on_mapped_walls_are_not_marked():
    obs = layer()
    # From (0, 0) the wall cells are at 4.95 m: stand 1 m from the east wall instead.
    assert not obs.update(Pose2D(3.95, 0.0, 0.0), scan({0: 1.0}))
    assert not obs.marks.any()


def test_marks_beyond_the_window_survive_a_scan():
    obs = layer()
    assert obs.update(Pose2D(-4.0, -4.0, 0.0), scan({90: 0.5}))  # mark at (-4, -3.5)
    before = obs.marks.copy()
    # Far away (> raytrace range): a scan with no returns clears nothing there.
    assert not obs.update(Pose2D(3.0, 3.0, 0.0), scan({}))
    assert np.array_equal(obs.marks, before)
    # Back near it, a free beam through it clears it.
    assert obs.update(Pose2D(-4.0, -4.0, 0.0), scan({}))
    assert not obs.marks.any()


def test_obstacle_distance_is_computed_once_per_mask_and_read_only():
    grid = room()
    blocked = grid.data != FREE
    a = obstacle_distance(blocked, grid.resolution)
    b = obstacle_distance(blocked.copy(), grid.resolution)
    assert a is b
    assert not a.flags.writeable
    expected = (distance_transform_edt(~blocked) * grid.resolution).astype(np.float32)
    assert np.array_equal(a, expected)
    other = blocked.copy()
    other[100, 100] = True
    c = obstacle_distance(other, grid.resolution)
    assert c is not a and c[100, 100] == 0.0
    with pytest.raises(ValueError):
        a[0, 0] = 1.0


def test_patched_costmap_matches_a_full_rebuild():
    obs = layer()
    rng = np.random.default_rng(2)
    for k in range(8):
        pose = Pose2D(*rng.uniform(-3.5, 3.5, size=2), rng.uniform(-3.0, 3.0))
        ranges = {int(i): float(rng.uniform(0.3, 2.4)) for i in rng.integers(0, BEAMS, 40)}
        obs.update(pose, scan(ranges, default=math.inf if k % 2 else 2.5))
        assert obs.has_marks == bool(obs.marks.any())
        full = obs.static.with_obstacles(obs.marks)
        assert np.array_equal(obs.costmap.cost, full.cost)
        reach = obs.static.robot_radius + obs.static.config.inflation_radius
        near = full.distance <= reach
        assert np.array_equal(obs.costmap.distance[near], full.distance[near])
    assert obs.marks.any()
    obs.clear()
    assert obs.costmap is obs.static and not obs.has_marks
