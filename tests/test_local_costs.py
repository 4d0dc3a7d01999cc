"""Map-size-independent pieces: the rolling-window obstacle layer and the cached
distance transforms (in memory, and stored on disk for later processes)."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from agv_mission import stored
from agv_mission.geometry import Pose2D
from agv_mission.maps import map_cache
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


def test_stored_tables_are_read_back_by_a_later_process(tmp_path, monkeypatch):
    """A fresh process (here: the memory cache cleared) reads the table from disk instead
    of building it; a damaged file, or a store that cannot be written, costs only a build."""
    store = tmp_path / "store"
    monkeypatch.setenv(stored.STORE_ENV, str(store))
    grid = room()
    blocked = grid.data != FREE
    builds = []

    def build() -> np.ndarray:
        builds.append(1)
        return (distance_transform_edt(~blocked) * grid.resolution).astype(np.float32)

    map_cache.clear()
    built = map_cache.stored_array_table("test_distance", blocked, 0.05, build)
    [table_file] = store.glob("test_distance-*.npy")
    map_cache.clear()
    read = map_cache.stored_array_table("test_distance", blocked, 0.05, build)
    assert len(builds) == 1 and read is not built
    assert read.dtype == np.float32 and np.array_equal(read, built)
    assert not read.flags.writeable
    map_cache.clear()  # another resolution is another table
    map_cache.stored_array_table("test_distance", blocked, 0.1, build)
    assert len(builds) == 2 and len(list(store.glob("test_distance-*.npy"))) == 2

    table_file.write_bytes(table_file.read_bytes()[:100])  # cut short
    map_cache.clear()
    assert np.array_equal(
        map_cache.stored_array_table("test_distance", blocked, 0.05, build), built
    )
    assert len(builds) == 3 and np.array_equal(np.load(table_file), built)  # stored again, whole

    monkeypatch.setenv(stored.STORE_ENV, str(table_file / "below_a_file"))  # cannot be written
    map_cache.clear()
    assert np.array_equal(
        map_cache.stored_array_table("test_distance", blocked, 0.05, build), built
    )
    assert len(builds) == 4


def test_stored_tables_are_bounded_least_recently_used_first(tmp_path, monkeypatch):
    store = tmp_path / "store"
    monkeypatch.setenv(stored.STORE_ENV, str(store))
    monkeypatch.setattr(stored, "MAX_STORED", 3)
    map_cache.clear()
    masks = [np.eye(4, k=k, dtype=bool) for k in range(4)]
    for mask in masks[:3]:
        map_cache.stored_array_table("test_mask", mask, None, lambda m=mask: ~m)
        for path in store.glob("*.npy"):  # distinct ages, whatever the clock's resolution
            os.utime(path, (path.stat().st_atime, path.stat().st_mtime - 10))
    map_cache.clear()
    map_cache.stored_array_table("test_mask", masks[0], None, lambda: ~masks[0])  # used: newest
    map_cache.stored_array_table("test_mask", masks[3], None, lambda: ~masks[3])
    assert len(list(store.glob("*.npy"))) == 3
    map_cache.clear()
    rebuilt = []
    for i in (0, 2, 3, 1):
        map_cache.stored_array_table(
            "test_mask", masks[i], None, lambda i=i: rebuilt.append(i) or ~masks[i]
        )
    assert rebuilt == [1]  # the least recently used was dropped


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
