"""``odometry``: dead reckoning from wheel encoders, anchored at the initial pose."""

from __future__ import annotations

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.localization.base import LocalizerDiagnostics
from agv_mission.localization.configs import OdometryConfig
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan


class OdometryLocalizer:
    Config = OdometryConfig

    def __init__(
        self, config: OdometryConfig, grid: OccupancyGrid, rng: np.random.Generator
    ) -> None:
        self.config = config
        self._start = Pose2D(0.0, 0.0, 0.0)
        self._odom0 = Pose2D(0.0, 0.0, 0.0)

    def reset(self, pose: Pose2D, odom: Pose2D) -> None:
        self._start, self._odom0 = pose, odom

    def update(self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float) -> Pose2D:
        return self._start.compose(odom.relative_to(self._odom0))

    def request_nomotion_update(self) -> None:
        """Nothing to refine without a filter."""

    def diagnostics(self) -> LocalizerDiagnostics:
        return LocalizerDiagnostics()
