"""Sensor messages passed between layers (the ROS message types this project needs)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agv_mission.geometry import Pose2D


@dataclass
class LaserScan:
    """One planar scan, like ``sensor_msgs/LaserScan``.

    ``ranges[i]`` is the range of the beam at ``angle_min + i * angle_increment`` in the
    robot frame; ``inf`` means no valid return (beyond ``range_max``, closer than
    ``range_min``, or dropped).
    """

    ranges: np.ndarray  # float32 (n,)
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    time: float

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(len(self.ranges))

    def valid(self) -> np.ndarray:
        return np.isfinite(self.ranges)

    def points(self, pose: Pose2D) -> np.ndarray:
        """Map-frame end points (M, 2) of the valid returns, seen from ``pose``."""
        ok = self.valid()
        r = self.ranges[ok].astype(float)
        a = self.angles[ok] + pose.yaw
        return np.stack([pose.x + r * np.cos(a), pose.y + r * np.sin(a)], axis=1)
