"""Costmaps: a static layer from the known map, inflated by the robot's footprint.

Unknown cells count as obstacles (a robot plans only through space it knows is free).
The distance field (metres from each cell centre to the nearest obstacle cell) is the
one quantity planners need: a point is traversable when its clearance exceeds the
robot's inscribed radius, and the inflation cost decays with clearance as in ROS's
``inflation_layer``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agv_mission.maps.costmap_config import CostmapConfig, ObstacleLayerConfig
from agv_mission.maps.distance import obstacle_distance
from agv_mission.maps.grid import FREE, OccupancyGrid

LETHAL = 254
INSCRIBED = 253

__all__ = [
    "INSCRIBED",
    "LETHAL",
    "Costmap",
    "CostmapConfig",
    "ObstacleLayerConfig",
    "inflation_cost",
]


@dataclass
class Costmap:
    """Static + inflation layers over an :class:`OccupancyGrid`."""

    grid: OccupancyGrid
    robot_radius: float
    config: CostmapConfig
    distance: np.ndarray  # float32 (H, W), metres to the nearest obstacle cell
    cost: np.ndarray  # uint8 (H, W), ROS costmap_2d values 0..254

    @classmethod
    def from_grid(
        cls, grid: OccupancyGrid, robot_radius: float, config: CostmapConfig | None = None
    ) -> Costmap:
        config = config or CostmapConfig()
        if config.resolution is not None:
            grid = grid.resampled(config.resolution)
        blocked = grid.data != FREE if config.unknown_is_obstacle else grid.data > 50
        distance = obstacle_distance(blocked, grid.resolution)  # cached per map
        cost = inflation_cost(distance, robot_radius, config)
        return cls(grid, robot_radius, config, distance, cost)

    @property
    def resolution(self) -> float:
        return self.grid.resolution

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Distance to the nearest obstacle at map-frame points (0 outside the grid)."""
        rows, cols = self.grid.world_to_cell(xy)
        inside = self.grid.in_bounds(rows, cols)
        out = np.zeros(rows.shape, dtype=np.float32)
        out[inside] = self.distance[rows[inside], cols[inside]]
        return out

    def is_free(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """True where the robot's footprint (plus ``margin``) fits at map-frame points."""
        return self.clearance(xy) > self.robot_radius + margin

    def with_obstacles(self, marks: np.ndarray) -> Costmap:
        """This costmap with the cells of ``marks`` (H, W bool) added as obstacles.

        Only a window around the marks is recomputed: beyond the footprint plus inflation
        an obstacle changes nothing a planner looks at.
        """
        if not marks.any():
            return self
        from scipy.ndimage import distance_transform_edt  # ~0.5 s: a run's, not a check's

        rows, cols = np.nonzero(marks)
        pad = int(
            np.ceil((self.robot_radius + self.config.inflation_radius + 0.5) / self.resolution)
        )
        r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, marks.shape[0])
        c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, marks.shape[1])
        window = (slice(r0, r1), slice(c0, c1))
        near = (distance_transform_edt(~marks[window]) * self.resolution).astype(np.float32)
        distance = self.distance.copy()
        distance[window] = np.minimum(distance[window], near)
        cost = self.cost.copy()
        cost[window] = inflation_cost(distance[window], self.robot_radius, self.config)
        return Costmap(self.grid, self.robot_radius, self.config, distance, cost)

    def cost_at(self, xy: np.ndarray) -> np.ndarray:
        rows, cols = self.grid.world_to_cell(xy)
        inside = self.grid.in_bounds(rows, cols)
        out = np.full(rows.shape, LETHAL, dtype=np.uint8)
        out[inside] = self.cost[rows[inside], cols[inside]]
        return out


def inflation_cost(distance: np.ndarray, robot_radius: float, config: CostmapConfig) -> np.ndarray:
    cost = np.zeros(distance.shape, dtype=np.uint8)
    decay = 252.0 * np.exp(-config.cost_scaling_factor * (distance - robot_radius))
    inflated = distance <= robot_radius + config.inflation_radius
    cost[inflated] = np.clip(decay[inflated], 1, 252).astype(np.uint8)
    cost[distance <= robot_radius] = INSCRIBED
    cost[distance <= 0.0] = LETHAL
    return cost
