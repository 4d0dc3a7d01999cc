"""What ``validate`` answers without scipy (issue 16: start-up): a built-in world's flood
fill and a costmap's point queries before its distance field exists give scipy's numbers,
cell for cell."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import label

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.grid import FREE, OccupancyGrid
from agv_mission.maps.rasterize import flood_fill
from agv_mission.maps.world_loader import load_world


def test_flood_fill_is_scipys_four_connected_label() -> None:
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(200):
        h, w = (int(n) for n in rng.integers(1, 50, 2))
        passable = rng.random((h, w)) < rng.uniform(0.3, 0.9)
        row, col = int(rng.integers(0, h)), int(rng.integers(0, w))
        labels, _ = label(passable)
        want = labels == labels[row, col] if passable[row, col] else np.zeros_like(passable)
        assert np.array_equal(flood_fill(passable, row, col), want)
        checked += int(passable[row, col])
    assert checked > 100


@pytest.mark.parametrize("world", ["turtlebot3_world", "small_house"])
@pytest.mark.parametrize("config", [CostmapConfig(), CostmapConfig(resolution=0.1)])
def test_point_queries_before_the_field_are_the_fields(world: str, config: CostmapConfig) -> None:
    grid = load_world(world).map
    built = Costmap.from_grid(grid, 0.105, config)
    built.distance  # noqa: B018 (built now)
    rng = np.random.default_rng(1)
    x0, x1, y0, y1 = grid.extent
    near_walls = 0
    for _ in range(200):
        n = int(rng.integers(1, 4))
        xy = np.column_stack(
            [rng.uniform(x0 - 0.2, x1 + 0.2, n), rng.uniform(y0 - 0.2, y1 + 0.2, n)]
        )
        margin = float(rng.choice([0.0, 0.05, 0.3, 2.0]))
        lazy = Costmap.from_grid(grid, 0.105, config)
        free = lazy.is_free(xy, margin)
        assert lazy._distance is None  # answered from the cells around each point
        assert np.array_equal(free, built.is_free(xy, margin))
        clearance = lazy.clearance(xy)
        assert clearance.dtype == np.float32
        assert np.array_equal(clearance, built.clearance(xy))
        near_walls += int(np.count_nonzero(~free))
    assert near_walls > 20


def test_a_grid_without_obstacles_asks_the_field() -> None:
    """scipy's distance transform of a grid without obstacles measures to a point off the
    grid: the point queries give its numbers, not infinity."""
    grid = OccupancyGrid(np.full((20, 30), FREE, dtype=np.int8), 0.05, Pose2D(0.0, 0.0, 0.0))
    lazy = Costmap.from_grid(grid, 0.105)
    point = np.array([0.02, 0.02])
    assert not lazy.is_free(point)
    assert lazy.clearance(point) == Costmap.from_grid(grid, 0.105).distance[0, 0]
