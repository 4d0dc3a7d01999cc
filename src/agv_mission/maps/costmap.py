"""Costmaps: a static layer from the known map, inflated by the robot's footprint.

Unknown cells count as obstacles (a robot plans only through space it knows is free).
The distance field (metres from each cell centre to the nearest obstacle cell) is the
one quantity planners need: a point is traversable when its clearance exceeds the
robot's inscribed radius, and the inflation cost decays with clearance as in ROS's
``inflation_layer``.

A costmap made by :meth:`Costmap.from_grid` builds its distance field (scipy's
distance transform) when something first reads it. Until then a question about a few
points (:meth:`Costmap.is_free`, :meth:`Costmap.clearance`) is answered from the cells
around them, with the very numbers the field would hold: ``agv-mission validate``
checks a mission's poses without scipy (~0.3 s to import) or the whole field.
"""

from __future__ import annotations

import math

import numpy as np

from agv_mission.maps.costmap_config import CostmapConfig, ObstacleLayerConfig
from agv_mission.maps.distance import obstacle_distance
from agv_mission.maps.grid import FREE, OccupancyGrid

LETHAL = 254
INSCRIBED = 253
_FEW_POINTS = 16  # point queries answered from the cells around them, before the field exists
_NEAR_CELLS = 64  # cells around a point a clearance query looks through, field unbuilt

__all__ = [
    "INSCRIBED",
    "LETHAL",
    "Costmap",
    "CostmapConfig",
    "ObstacleLayerConfig",
    "inflation_cost",
]


class Costmap:
    """Static + inflation layers over an :class:`OccupancyGrid`."""

    def __init__(
        self,
        grid: OccupancyGrid,
        robot_radius: float,
        config: CostmapConfig,
        distance: np.ndarray | None = None,
        cost: np.ndarray | None = None,
    ) -> None:
        self.grid = grid
        self.robot_radius = robot_radius
        self.config = config
        self._distance = distance  # None: built from the grid when first read
        self._cost = cost
        self._has_obstacles: bool | None = None

    @classmethod
    def from_grid(
        cls, grid: OccupancyGrid, robot_radius: float, config: CostmapConfig | None = None
    ) -> Costmap:
        config = config or CostmapConfig()
        if config.resolution is not None:
            grid = grid.resampled(config.resolution)
        return cls(grid, robot_radius, config)

    @property
    def distance(self) -> np.ndarray:
        """float32 (H, W), metres from each cell centre to the nearest obstacle cell."""
        if self._distance is None:
            self._distance = obstacle_distance(self._blocked(), self.grid.resolution)  # cached
        return self._distance

    @property
    def cost(self) -> np.ndarray:
        """uint8 (H, W), ROS costmap_2d values 0..254."""
        if self._cost is None:
            self._cost = inflation_cost(self.distance, self.robot_radius, self.config)
        return self._cost

    def _blocked(self, data: np.ndarray | None = None) -> np.ndarray:
        """Obstacle cells of ``data`` (default: the whole grid)."""
        data = self.grid.data if data is None else data
        return data != FREE if self.config.unknown_is_obstacle else data > 50

    @property
    def resolution(self) -> float:
        return self.grid.resolution

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Distance to the nearest obstacle at map-frame points (0 outside the grid)."""
        rows, cols = self.grid.world_to_cell(xy)
        inside = self.grid.in_bounds(rows, cols)
        out = np.zeros(rows.shape, dtype=np.float32)
        near = self._near(rows[inside], cols[inside], _NEAR_CELLS)
        if near is not None and bool(np.all(np.isfinite(near))):
            out[inside] = near
        else:
            out[inside] = self.distance[rows[inside], cols[inside]]
        return out

    def is_free(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """True where the robot's footprint (plus ``margin``) fits at map-frame points."""
        reach = self.robot_radius + margin
        rows, cols = self.grid.world_to_cell(xy)
        inside = self.grid.in_bounds(rows, cols)
        near = self._near(rows[inside], cols[inside], math.ceil(reach / self.resolution) + 1)
        if near is None:
            return self.clearance(xy) > reach
        out = np.zeros(rows.shape, dtype=np.float32)
        out[inside] = near
        return out > reach

    def _near(self, rows: np.ndarray, cols: np.ndarray, cells: int) -> np.ndarray | None:
        """:attr:`distance` at a few cells ``(rows, cols)`` of the grid, read from the
        ``cells`` around each while the field is not built: the same float32 numbers where
        an obstacle lies that near, infinity where none does. None once the field is
        built, for many points, or for a grid without obstacles (where the distance
        transform measures to a point off the grid)."""
        if self._distance is not None or np.size(rows) > _FEW_POINTS:
            return None
        data = self.grid.data
        if self._has_obstacles is None:
            self._has_obstacles = bool(self._blocked(data).any())
        if not self._has_obstacles:
            return None
        h, w = data.shape
        cells = max(int(cells), 1)
        out = np.full(np.shape(rows), np.inf, dtype=np.float32)
        for i, (r, c) in enumerate(
            zip(np.ravel(rows).tolist(), np.ravel(cols).tolist(), strict=True)
        ):
            r0, c0 = max(r - cells, 0), max(c - cells, 0)
            window = self._blocked(data[r0 : r + cells + 1, c0 : c + cells + 1])
            near_r, near_c = np.nonzero(window)
            squared = (near_r + (r0 - r)) ** 2 + (near_c + (c0 - c)) ** 2
            if len(squared) and int(squared.min()) <= cells * cells:  # none outside is nearer
                # the distance transform's arithmetic: sqrt in float64, times the cell size
                out.flat[i] = np.float32(math.sqrt(float(squared.min())) * self.resolution)
        return out

    def with_obstacles(self, marks: np.ndarray) -> Costmap:
        """This costmap with the cells of ``marks`` (H, W bool) added as obstacles.

        Only a window around the marks is recomputed: beyond the footprint plus inflation
        an obstacle changes nothing a planner looks at.
        """
        if not marks.any():
            return self
        rows, cols = np.nonzero(marks)
        pad = int(
            np.ceil((self.robot_radius + self.config.inflation_radius + 0.5) / self.resolution)
        )
        r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, marks.shape[0])
        c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, marks.shape[1])
        window = (slice(r0, r1), slice(c0, c1))
        from scipy.ndimage import distance_transform_edt  # the field is built by now

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
