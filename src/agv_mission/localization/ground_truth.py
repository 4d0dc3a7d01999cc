"""``ground_truth``: the simulator's pose, for testing everything above localisation."""

from __future__ import annotations

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.localization.base import LocalizerDiagnostics
from agv_mission.localization.configs import GroundTruthConfig
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan


class GroundTruthLocalizer:
    Config = GroundTruthConfig

    def __init__(
        self, config: GroundTruthConfig, grid: OccupancyGrid, rng: np.random.Generator
    ) -> None:
        self.config = config

    def reset(self, pose: Pose2D, odom: Pose2D) -> None:
        """Nothing to reset: the truth needs no initial guess."""

    def update(self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float) -> Pose2D:
        return truth

    def request_nomotion_update(self) -> None:
        """Nothing to refine without a filter."""

    def diagnostics(self) -> LocalizerDiagnostics:
        return LocalizerDiagnostics()
