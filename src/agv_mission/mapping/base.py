"""What every SLAM plugin speaks."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan


class Slam(Protocol):
    """Builds a map while estimating the pose in it. Built as ``cls(config, bounds=...,
    rng=...)`` and fed like a localiser: once per control step, odometry and the newest
    scan (``None`` when none arrived), and once per scan a faster lidar took between.

    :meth:`finish` and :meth:`reframe` are what ``agv-mission map`` asks once a recording
    has been fed; a plugin that subclasses this protocol inherits their defaults (nothing
    to finish; a map that stays in the frame SLAM started in)."""

    integrations: int  # scans added to the map so far
    trajectory: list[tuple[float, float, float, float]]  # (t, x, y, yaw) per scan

    @property
    def pose(self) -> Pose2D:
        """The corrected pose at the last processed scan."""
        ...

    @property
    def covariance(self) -> np.ndarray:
        """(3, 3) covariance of :attr:`pose` (x, y, yaw)."""
        ...

    def reset(self, pose: Pose2D, odom: Pose2D) -> None: ...

    def update(
        self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float
    ) -> Pose2D: ...

    def occupancy_grid(self) -> OccupancyGrid:
        """The map so far."""
        ...

    def diagnostics(self) -> dict[str, float]:
        """Counters a run may report (scans matched, matches rejected, ...)."""
        ...

    def finish(self) -> None:
        """The whole recording has been fed (``agv-mission map``): a last pass over it,
        e.g. smoothing the trajectory. By default there is none."""

    def reframe(self, transform: Pose2D) -> bool:
        """Move the map frame: every pose ``p`` becomes ``transform ∘ p`` and the map moves
        with them (``agv-mission map`` lines a finished map up with the frame the robot
        localised in); whether it did.

        By default it does not, and says so: a plugin that keeps only its grid could
        move it by resampling alone, which smears every wall by a cell, so the map stays
        in the frame SLAM started in."""
        return False
