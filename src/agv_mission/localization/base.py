"""What every localisation plugin speaks."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.sensor_msgs import LaserScan


@dataclass
class LocalizerDiagnostics:
    """The numbers a localiser shows the runner (metrics, plots, live views).

    Every field has an empty default: a localiser without a filter reports nothing.
    """

    filter_updates: int = 0  # how many times the filter used a scan so far
    particle_counts: list[tuple[float, int]] = field(default_factory=list)  # (t, n) per update
    snapshots: list[tuple[float, np.ndarray]] = field(default_factory=list)  # for plots
    particles: np.ndarray | None = None  # (n, 3) the current cloud
    covariance: np.ndarray | None = None  # (3, 3) of the estimate (x, y, yaw)


class Localizer(Protocol):
    """Estimates the robot's pose in the map frame.

    Plugins are constructed as ``cls(config, grid=..., rng=...)`` and fed once per control
    step with the odometry pose (odom frame), the newest scan (``None`` when no new scan
    arrived) and the true pose; a lidar faster than the control loop feeds them also
    once per scan taken between steps, with the odometry and the time of that scan.
    Only ``ground_truth`` may look at the true pose; it is passed to all so the runner
    stays plugin-agnostic.
    """

    def reset(self, pose: Pose2D, odom: Pose2D) -> None: ...

    def update(
        self, odom: Pose2D, scan: LaserScan | None, truth: Pose2D, time: float
    ) -> Pose2D: ...

    def request_nomotion_update(self) -> None:
        """Refine the estimate with the next scan even though the robot stands still."""

    def diagnostics(self) -> LocalizerDiagnostics:
        """Filter statistics so far (empty for a localiser without a filter)."""
        ...
