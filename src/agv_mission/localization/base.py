"""What every localisation plugin speaks."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.messages import LaserScan


class Localizer(Protocol):
    """Estimates the robot's pose in the map frame.

    Plugins are constructed as ``cls(config, grid=..., rng=...)`` and fed once per control
    step with the odometry pose (odom frame), the newest scan (``None`` when no new scan
    arrived) and the true pose. Only ``ground_truth`` may look at the true pose; it is
    passed to all so the runner stays plugin-agnostic.
    """

    def reset(self, pose: Pose2D, odom: Pose2D) -> None: ...

    def update(
        self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float
    ) -> Pose2D: ...

    def request_nomotion_update(self) -> None:
        """Refine the estimate with the next scan even though the robot stands still."""

    @property
    def covariance(self) -> np.ndarray | None:
        """3x3 covariance (x, y, yaw) of the latest estimate; None when there is none."""
