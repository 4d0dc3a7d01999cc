"""Known ground for ``map_area`` to drive back to when SLAM's estimate grows uncertain.

An explorer that drives on while its scans match too little (open floor, a lone wall)
carries the estimate's error into every wall it adds to the map. Driving back to where
the estimate was sure lets the scans meet the map as it was built then, so the scan
matcher (and a ``graph`` SLAM's loop closure) pulls the estimate back before exploring
on (:class:`~agv_mission.behaviors.explore.MapArea`).
"""

from __future__ import annotations

import math

import numpy as np

from agv_mission.mapping.frontiers import path_lengths
from agv_mission.maps.costmap import Costmap
from agv_mission.robots.description import LidarSpec


def revisit_sigma(lidar: LidarSpec, feature_range: float) -> float:
    """SLAM's position std (m) past which an explorer drives back to known ground: the
    lidar's range precision (two standard deviations of its range noise, the figure a
    datasheet quotes: the LDS-01's +-3.5 %) at ``feature_range``, where scans are
    matched against structure. A pose less certain than that puts each new wall into the
    map farther off than the lidar's own scatter of the walls already there, and beyond
    a cell (5 cm) off them: a second wall beside the first, a wall that is not there for
    the patrol on the saved map."""
    return 2.0 * max(lidar.noise_std, lidar.noise_fraction * feature_range)


class KnownGround:
    """The places where a scan match pinned SLAM's pose, ``SPACING`` apart, and the one
    to drive back to.

    Such a place is one where the std fell (a match pulled it in: on open floor, where
    the scans match too little, it only grows with the odometry) to under
    ``SURE_SIGMA``. A std that is merely still small is no such place: a few metres
    into open floor it has not grown much yet, but the scans there never met the map."""

    SURE_SIGMA = 0.015  # m: near walls a refined match pins the pose to about a centimetre
    SPACING = 0.5  # m between remembered places
    MIN_DISTANCE = 1.0  # m: a place nearer is where the robot already is

    def __init__(self) -> None:
        self.places: list[tuple[float, float]] = []
        self._sigma = float("inf")  # the std at the last note

    def note(self, x: float, y: float, sigma: float) -> None:
        """Remember ``(x, y)`` if the std ``sigma`` fell there to a sure one and it is
        new ground."""
        fell, self._sigma = sigma < self._sigma, sigma
        if not fell or sigma >= self.SURE_SIGMA:
            return
        if self.places:
            px, py = self.places[-1]
            if math.hypot(x - px, y - py) < self.SPACING:
                return
        self.places.append((x, y))

    def nearest(
        self, costmap: Costmap, robot: tuple[float, float], clearance: float
    ) -> tuple[float, float] | None:
        """The remembered place nearest by driving on ``costmap`` (where the robot's
        footprint fits with ``clearance``), at least ``MIN_DISTANCE`` from ``robot``;
        None when none is reachable."""
        if not self.places:
            return None
        grid = costmap.grid
        length = path_lengths(grid, robot, costmap.robot_radius, clearance)
        places = np.asarray(self.places)
        rows, cols = grid.world_to_cell(places)
        far = np.hypot(places[:, 0] - robot[0], places[:, 1] - robot[1]) >= self.MIN_DISTANCE
        ok = grid.in_bounds(rows, cols) & far
        cost = np.full(len(places), np.inf)
        cost[ok] = length[rows[ok], cols[ok]]
        best = int(np.argmin(cost))
        if not math.isfinite(cost[best]):
            return None
        return float(places[best, 0]), float(places[best, 1])
