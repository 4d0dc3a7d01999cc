"""The obstacle layer: what the lidar sees that the static map does not hold.

Every scan clears the cells its beams pass through and marks the cells its returns end
in, unless a mapped obstacle is already there (within ``map_tolerance``, so localisation
error does not paint the walls twice). The layered :class:`Costmap` the planners use is
the static one with the marked cells added.
"""

from __future__ import annotations

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, ObstacleLayerConfig
from agv_mission.messages import LaserScan


class ObstacleLayer:
    """Marks and clears unmapped obstacles on the static costmap's grid."""

    def __init__(self, static: Costmap, config: ObstacleLayerConfig) -> None:
        self.static = static
        self.config = config
        self.marks = np.zeros(static.distance.shape, dtype=bool)
        self._layered: Costmap | None = static

    @property
    def costmap(self) -> Costmap:
        """The static costmap with the marked obstacles added (recomputed when they change)."""
        if self._layered is None:
            self._layered = self.static.with_obstacles(self.marks)
        return self._layered

    def clear(self) -> None:
        """Forget every marked obstacle (the 'clear costmap' recovery)."""
        if self.marks.any():
            self.marks[:] = False
            self._layered = self.static

    def update(self, pose: Pose2D, scan: LaserScan) -> bool:
        """Clear along the beams and mark the returns of ``scan`` seen from ``pose``."""
        if not self.config.enabled:
            return False
        grid = self.static.grid
        res = grid.resolution
        angles = scan.angles + pose.yaw
        ranges = np.where(np.isfinite(scan.ranges), scan.ranges, np.inf)
        reach = np.minimum(ranges - res, self.config.raytrace_range)
        steps = np.arange(0.0, self.config.raytrace_range, res * 0.5)
        along = steps[None, :] < reach[:, None]
        dirs = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        pts = np.array([pose.x, pose.y]) + steps[None, :, None] * dirs[:, None, :]
        before = self.marks.copy()
        self._set(pts[along], False)
        hit = np.isfinite(ranges) & (ranges <= self.config.max_range)
        ends = np.array([pose.x, pose.y]) + ranges[hit, None] * dirs[hit]
        if len(ends):
            unmapped = self.static.clearance(ends) > self.config.map_tolerance
            self._set(ends[unmapped], True)
        changed = not np.array_equal(before, self.marks)
        if changed:
            self._layered = None
        return changed

    def _set(self, xy: np.ndarray, value: bool) -> None:
        rows, cols = self.static.grid.world_to_cell(xy)
        inside = self.static.grid.in_bounds(rows, cols)
        self.marks[rows[inside], cols[inside]] = value
