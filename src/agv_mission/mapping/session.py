"""A mapping session: SLAM owns the pose and the map while an area is being explored."""

from __future__ import annotations

import numpy as np

from agv_mission.geometry import Bounds, Pose2D
from agv_mission.mapping.base import Slam
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.grid import UNKNOWN, OccupancyGrid
from agv_mission.sensor_msgs import LaserScan


class MappingSession:
    """Feeds odometry and scans to a SLAM plugin; serves its growing map as a costmap.

    The costmap is rebuilt from the SLAM map at most every ``refresh_period`` simulated
    seconds: a distance transform per scan would cost more than the mapping itself.
    """

    def __init__(
        self,
        slam: Slam,
        bounds: Bounds,
        robot_radius: float,
        costmap_config: CostmapConfig,
        refresh_period: float = 1.0,
    ) -> None:
        self.slam = slam
        self.bounds = bounds
        self.robot_radius = robot_radius
        # The SLAM map already holds every obstacle the lidar saw: no separate layer.
        self.costmap_config = costmap_config.model_copy(
            update={"obstacles": costmap_config.obstacles.model_copy(update={"enabled": False})}
        )
        self.refresh_period = refresh_period
        self._next_refresh = 0.0
        self._costmap: Costmap | None = None

    def start(self, pose: Pose2D, odom: Pose2D) -> None:
        self.slam.reset(pose, odom)

    def update(self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float) -> Pose2D:
        return self.slam.update(odom, scan, truth, time)

    @property
    def grid(self) -> OccupancyGrid:
        return self.slam.occupancy_grid()

    def refreshed_costmap(self, time: float) -> Costmap | None:
        """A new costmap of the map so far when one is due, else ``None``."""
        if time < self._next_refresh - 1e-9 or self.slam.integrations == 0:
            return None
        self._next_refresh = time + self.refresh_period
        self._costmap = Costmap.from_grid(self.grid, self.robot_radius, self.costmap_config)
        return self._costmap

    @property
    def costmap(self) -> Costmap | None:
        """The last costmap handed out (what the navigator plans on), ``None`` before one.

        An explorer must pick its goals on this map's grid, not on the newer
        :attr:`grid`: a goal that is free on the newer map may still be unknown (an
        obstacle) on the planner's, and fail at once.
        """
        return self._costmap

    def request_refresh(self) -> None:
        """Make the next :meth:`refreshed_costmap` call build a new costmap."""
        self._next_refresh = 0.0

    def known_fraction(self) -> float:
        """The share of the bounds' cells that the map knows (free or occupied)."""
        grid = self.grid
        xmin, xmax, ymin, ymax = self.bounds
        rows, cols = np.indices(grid.data.shape)
        centres = grid.cell_to_world(rows, cols)
        inside = (
            (centres[..., 0] >= xmin)
            & (centres[..., 0] <= xmax)
            & (centres[..., 1] >= ymin)
            & (centres[..., 1] <= ymax)
        )
        total = (xmax - xmin) * (ymax - ymin) / grid.resolution**2
        known = np.count_nonzero(inside & (grid.data != UNKNOWN))
        return float(min(known / max(total, 1.0), 1.0))
