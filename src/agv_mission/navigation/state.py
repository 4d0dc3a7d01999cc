"""What the navigation stack and the behaviours know about the robot at a control step."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from agv_mission.geometry import Pose2D, wrap_angles
from agv_mission.messages import LaserScan


@dataclass
class RobotState:
    """The robot as its software sees it (estimated, never true, pose)."""

    time: float
    estimate: Pose2D
    velocity: tuple[float, float] = (0.0, 0.0)  # the last command (v, w)
    scan: LaserScan | None = None  # the newest scan
    obstacles: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # map-frame points

    def range_ahead(self, half_width: float) -> float:
        """Smallest valid range within +-``half_width`` radians of straight ahead."""
        if self.scan is None:
            return float("inf")
        angles = np.abs(wrap_angles(self.scan.angles))
        sector = self.scan.ranges[angles <= half_width]
        finite = sector[np.isfinite(sector)]
        return float(finite.min()) if finite.size else float("inf")
